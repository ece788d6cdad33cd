//! Scene files (RON): the layers to show, their parameters, and the camera. The viewer saves and loads
//! them; `fascicle render scene.ron` renders one. The default scene is built in code from the phantom, so
//! nothing needs files.

use std::path::{Path, PathBuf};

use fascicle_core::dti::glyph::TensorShape;
use fascicle_core::io::BvecConvention;
use fascicle_core::io::classify::{ImageKind, TensorOrder};
use fascicle_core::roi::{Roi, RoiMode, RoiShape};
use fascicle_core::sh::ShBasis;
use fascicle_core::sh::glyph::{GlyphPlane, GlyphStyle, Sampling};
use fascicle_sh_glyphs::RayCastSettings;
use fascicle_tensors::TensorGlyphSettings;
use fascicle_tensors::splat::SplatSettings;
use fascicle_tracts::TubeSettings;
use fascicle_volume::VolumeSettings;
use serde::{Deserialize, Serialize};

/// A scene: what a scene file holds.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Scene {
    /// The layers, in list order (later ones over earlier ones in the 2D views).
    pub layers: Vec<LayerSpec>,
    /// The 3D view's camera; [`CameraSpec::default`] when absent.
    #[serde(default)]
    pub camera: CameraSpec,
    /// The layout (3D alone or with three orthogonal 2D views), the crosshair and the colour bars.
    #[serde(default)]
    pub views: fascicle_views::Views,
}

/// One layer of a scene: its name, visibility, opacity and what it shows.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LayerSpec {
    /// The name the viewer lists it by and its colour bar shows.
    pub name: String,
    /// Defaults to true.
    #[serde(default = "yes")]
    pub visible: bool,
    /// 0..1. Defaults to 1.
    #[serde(default = "one")]
    pub opacity: f32,
    /// What the layer shows, from which source, with which settings.
    pub kind: LayerKind,
}

fn yes() -> bool {
    true
}
fn one() -> f32 {
    1.0
}
fn one_usize() -> usize {
    1
}

/// What a layer shows, with its parameters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum LayerKind {
    /// One slice of a scalar volume, drawn in its place in world space.
    Slice {
        /// The image.
        source: VolumeSource,
        /// The voxel axis the slice is cut across; default Z (axial).
        #[serde(default)]
        axis: SliceAxis,
        /// The slice; the middle one when absent.
        #[serde(default)]
        index: Option<usize>,
        /// The values shown black and white (window/level); the minimum and the 99.5th percentile when
        /// absent. An edit re-cuts the slice from the image in memory; nothing is read again.
        #[serde(default)]
        window: Option<(f32, f32)>,
    },
    /// Streamlines as lines coloured by local direction.
    Tractogram {
        /// The tractogram file.
        path: PathBuf,
    },
    /// World axes from the origin: R red, A green, S blue.
    Axes {
        /// Length of each axis, mm.
        length_mm: f32,
    },
    /// Ray-cast ODF glyphs, one per voxel of a slice of an SH field.
    ShGlyphs {
        /// The SH field.
        source: ShSource,
        /// The voxel axis the slice is cut across; default Z (axial).
        #[serde(default)]
        axis: SliceAxis,
        /// The slice; the middle one when absent.
        #[serde(default)]
        index: Option<usize>,
        /// Every `spacing`-th voxel along each in-plane axis (1 = every voxel).
        #[serde(default = "one_usize")]
        spacing: usize,
        /// A free plane of interest (any orientation, spacing in mm), used instead of axis/index/spacing.
        #[serde(default)]
        plane: Option<GlyphPlane>,
        /// How a free plane reads the field.
        #[serde(default)]
        sampling: Sampling,
        /// Every voxel of the field (every `spacing`-th along each axis) instead of a plane.
        #[serde(default)]
        full_volume: bool,
        /// Glyph size, sharpening and normalisation (a change rebuilds the glyphs).
        #[serde(default)]
        style: GlyphStyle,
        /// The ray caster's method, knobs and colour (a uniform update only).
        #[serde(default)]
        render: RayCastSettings,
    },
    /// Tensor splats (EWA Gaussian footprints), one per voxel of a slab of `thickness` slices around a slice,
    /// coloured by FA (viridis) with opacity `opacity · FA`.
    TensorSplats {
        /// The tensor field.
        source: TensorSource,
        /// The voxel axis the slab is cut across; default Z (axial).
        #[serde(default)]
        axis: SliceAxis,
        /// The slab's centre slice; the middle one when absent.
        #[serde(default)]
        index: Option<usize>,
        /// Slices in the slab, centred on `index`; default 1.
        #[serde(default = "one_usize")]
        thickness: usize,
        /// Largest standard deviation as a fraction of the voxel size.
        #[serde(default = "splat_size")]
        size: f64,
        /// Only voxels with FA at or above this; default 0.
        #[serde(default)]
        min_fa: f64,
        /// Depth attenuation, opacity, lighting and colouring (no rebuild).
        #[serde(default)]
        render: SplatSettings,
    },
    /// Fibre tracts drawn as hyperstreamlines (ray-cast tubelets), polygon tubes or lines, with ROIs.
    Tracts {
        /// Where the streamlines come from.
        source: TractSource,
        /// How they are drawn; default hyperstreamlines.
        #[serde(default)]
        mode: TractMode,
        /// Cross-section scale and colour (a change rebuilds); method, iterations, tolerance and shading (uniform).
        #[serde(default)]
        render: TubeSettings,
        /// Include/exclude regions (AND): editing them re-selects, nothing is rebuilt.
        #[serde(default)]
        rois: Vec<Roi>,
        /// Include/exclude mask images (as `tckedit` takes an image as a region: a point in a non-zero voxel,
        /// the nearest voxel), with the regions above: a change re-selects once the images are read (nothing
        /// is rebuilt); cutting masks (`crop`) cut the streamlines, and a change of them rebuilds. Default
        /// none.
        #[serde(default)]
        masks: Vec<MaskRoi>,
        /// The regions (ROIs and masks) test only each streamline's first and last points (`tckedit
        /// -ends_only`); default false. A change re-selects.
        #[serde(default)]
        ends_only: bool,
        /// Streamlines deleted by hand (indices into the layer's streamlines as built: after its value
        /// threshold and cutting masks), sorted; hidden whatever the regions select, left out of a saved selection. A change
        /// re-selects. Default none.
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        deleted: Vec<u32>,
        /// What colours the streamlines (tubes and lines; polygon tubes keep their direction colours).
        #[serde(default)]
        colouring: TractColouring,
    },
    /// Direct volume rendering of a scalar volume (ray casting or 3D-texture slicing), composited with the
    /// opaque layers by depth.
    Volume {
        /// The image.
        source: VolumeSource,
        /// Method and step (a change rebuilds), transfer function and toggles (buffer and uniform updates).
        #[serde(default)]
        render: VolumeSettings,
    },
    /// Ray-cast tensor glyphs (ellipsoids or superquadrics), one per voxel of a slice.
    TensorGlyphs {
        /// The tensor field.
        source: TensorSource,
        /// The voxel axis the slice is cut across; default Z (axial).
        #[serde(default)]
        axis: SliceAxis,
        /// The slice; the middle one when absent.
        #[serde(default)]
        index: Option<usize>,
        /// Every `spacing`-th voxel along each in-plane axis (1 = every voxel, the default).
        #[serde(default = "one_usize")]
        spacing: usize,
        /// Largest radius as a fraction of the voxel size.
        #[serde(default = "glyph_size")]
        size: f64,
        /// Only voxels with FA at or above this.
        #[serde(default)]
        min_fa: f64,
        /// Ellipsoid or superquadric (a change rebuilds); gamma, search knobs, colour and shading (uniform).
        #[serde(default)]
        render: TensorGlyphSettings,
    },
}

fn glyph_size() -> f64 {
    0.9
}
fn splat_size() -> f64 {
    0.5
}

impl LayerKind {
    /// The kind without its draw-only settings: two kinds with the same structure differ only in what a
    /// uniform update can change, so the layer is not rebuilt or re-uploaded.
    pub fn structure(&self) -> LayerKind {
        match self {
            LayerKind::ShGlyphs { source, axis, index, spacing, plane, sampling, full_volume, style, .. } => {
                LayerKind::ShGlyphs {
                    source: source.clone(),
                    axis: *axis,
                    index: *index,
                    spacing: *spacing,
                    plane: *plane,
                    sampling: *sampling,
                    full_volume: *full_volume,
                    style: *style,
                    render: RayCastSettings::default(),
                }
            }
            LayerKind::TensorSplats { source, axis, index, thickness, size, min_fa, .. } => LayerKind::TensorSplats {
                source: source.clone(),
                axis: *axis,
                index: *index,
                thickness: *thickness,
                size: *size,
                min_fa: *min_fa,
                render: SplatSettings::default(),
            },
            LayerKind::TensorGlyphs { source, axis, index, spacing, size, min_fa, render } => LayerKind::TensorGlyphs {
                source: source.clone(),
                axis: *axis,
                index: *index,
                spacing: *spacing,
                size: *size,
                min_fa: *min_fa,
                // Ellipsoid or superquadric changes the buffer's bounds: structural. Gamma, knobs and colour
                // are uniform updates.
                render: TensorGlyphSettings {
                    shape: match render.shape {
                        TensorShape::Ellipsoid => TensorShape::Ellipsoid,
                        TensorShape::Superquadric { .. } => TensorShape::default(),
                    },
                    ..TensorGlyphSettings::default()
                },
            },
            // The ROIs and the per-pixel knobs are updated in place; sources, mode, scale and colour rebuild.
            LayerKind::Tracts { source, mode, render, colouring, masks, .. } => LayerKind::Tracts {
                source: source.clone(),
                mode: *mode,
                render: TubeSettings { scale: render.scale, colour: render.colour, ..TubeSettings::default() },
                rois: vec![],
                // Cutting masks cut the streamlines when the layer is built; include and exclude masks, and
                // the rule, re-select (`fascicle_tracts::TractMasks`).
                masks: masks.iter().filter(|m| m.crop).cloned().collect(),
                ends_only: false,
                deleted: vec![],
                colouring: colouring.clone(),
            },
            // Every setting is the volume plugin's to apply (`VolumeSettings`: a uniform, the tables, the proxy
            // mesh); only the image is structural.
            LayerKind::Volume { source, .. } => {
                LayerKind::Volume { source: source.clone(), render: VolumeSettings::default() }
            }
            // Axis, index and window are restyles: the views plugin cuts the slice again from the image the layer
            // holds (`fascicle_views::SliceSettings`).
            LayerKind::Slice { source, .. } => {
                LayerKind::Slice { source: source.clone(), axis: SliceAxis::Z, index: None, window: None }
            }
            other => other.clone(),
        }
    }
}

/// A mask image as a tract layer's region: a NIfTI or MRtrix image in the tractogram's world space (its first
/// volume; non-zero voxels are in the region).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MaskRoi {
    /// The image.
    pub path: PathBuf,
    /// Include (kept streamlines meet it) or exclude (streamlines that meet it are dropped). Default include.
    #[serde(default)]
    pub mode: RoiMode,
    /// The region cuts the streamlines instead (`tckedit -mask`; `mode` is not used): each kept streamline is
    /// cut where it leaves the layer's cutting masks, its runs of two or more points inside shown as
    /// streamlines. Default false.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub crop: bool,
    /// Voxels painted in the viewer (a brush in a 2D view): when present, the region is these voxels and `path`
    /// is where the viewer saves them as NIfTI (after every stroke, undo and redo); default none (the image at
    /// `path` is the region).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub painted: Option<PaintedMask>,
}

/// A mask painted voxel by voxel on an image's grid (the image the 2D views showed on top).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PaintedMask {
    /// The grid's size in voxels.
    pub dims: [usize; 3],
    /// Voxel to world (RAS+ mm): the 4x4 affine's columns.
    pub world_from_voxel: [[f64; 4]; 4],
    /// The painted voxels, as indices `x + nx * (y + ny * z)`: sorted, each once.
    pub voxels: Vec<u32>,
}

impl PaintedMask {
    /// An empty mask on the grid of `dims` voxels placed by `world_from_voxel`.
    pub fn on_grid(dims: [usize; 3], world_from_voxel: glam::DMat4) -> Self {
        Self { dims, world_from_voxel: world_from_voxel.to_cols_array_2d(), voxels: vec![] }
    }

    /// The mask as an image: 1 in the painted voxels, 0 elsewhere.
    pub fn volume(&self) -> fascicle_core::Volume<f32> {
        let affine = glam::DMat4::from_cols_array_2d(&self.world_from_voxel);
        let mut v = fascicle_core::Volume::<f32>::zeros(&self.dims, affine);
        for &i in &self.voxels {
            if let Some(x) = v.data.get_mut(i as usize) {
                *x = 1.0;
            }
        }
        v
    }

    /// Paints (or, with `erase`, clears) `voxels` (indices as [`Self::voxels`]; those outside the grid are left
    /// out).
    pub fn paint(&mut self, voxels: impl IntoIterator<Item = u32>, erase: bool) {
        let n = self.dims.iter().product::<usize>();
        let mut set: std::collections::BTreeSet<u32> = self.voxels.iter().copied().collect();
        for v in voxels.into_iter().filter(|v| (*v as usize) < n) {
            if erase {
                set.remove(&v);
            } else {
                set.insert(v);
            }
        }
        self.voxels = set.into_iter().collect();
    }
}

/// Where tracts come from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum TractSource {
    /// RK4 tracking (1 mm steps, FA 0.2) of the built-in phantom's tensors from every `seed_spacing`-th
    /// voxel with FA ≥ 0.3 of its middle axial slice; each point carries its tensor.
    PhantomRk4 {
        /// Seeds on every `seed_spacing`-th voxel along each in-plane axis (0 counts as 1).
        seed_spacing: usize,
    },
    /// A `.trk`/`.tck` file. With `tensors`, each point carries the tensor of that field where it lies
    /// (hyperstreamline sections); without, sections are circular.
    File {
        /// The tractogram file.
        path: PathBuf,
        /// The tensor field that gives each point its section; none: circular sections.
        #[serde(default)]
        tensors: Option<TensorSource>,
    },
    /// Deterministic tensor tracking (Euler, RK2 or RK4) through a tensor field, from `seeds`, run in the
    /// background with progress; each point carries its tensor. Changing an ROI re-selects these streamlines;
    /// changing the field, seeds or parameters tracks again.
    Track {
        /// The tensor field tracked through.
        tensors: TensorSource,
        /// Where streamlines start; default every 2nd voxel with FA at least 0.3.
        #[serde(default)]
        seeds: Seeds,
        /// Integrator, step, stopping and length limits; default RK4 at 0.5 mm, FA 0.2, 60 degrees, 0..250 mm.
        #[serde(default)]
        params: fascicle_core::tracking::TrackParams,
    },
    /// A peaks image (MRtrix (X,Y,Z,3N) or DIPY (X,Y,Z,N,3) layout, `fascicle peaks`): one short segment per
    /// peak through its voxel centre, the voxel's largest peak `length` voxels long, the others in proportion
    /// to their amplitudes. Drawn as lines by default.
    Peaks {
        /// The peaks image.
        path: PathBuf,
        /// Length of each voxel's largest peak, voxels; default 0.9.
        #[serde(default = "default_peak_length")]
        length: f32,
    },
}

/// What colours a tract layer's streamlines, as mrview's track colouring.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub enum TractColouring {
    /// The style's own: local direction, Westin shape or one colour per streamline (`TubeSettings::colour`).
    #[default]
    Style,
    /// Each streamline in the colour of the direction from its first to its last point (|x|, |y|, |z|).
    Ends,
    /// Each streamline by its length on viridis, 0 to `max_mm`.
    Length {
        /// The length shown at viridis' top end, mm.
        max_mm: f32,
    },
    /// A scalar image (FA, MD, ...) sampled (trilinear) at every point, on viridis over `window`.
    Scalar {
        /// The image sampled.
        source: VolumeSource,
        /// The values at viridis' two ends.
        window: (f32, f32),
    },
    /// A value per streamline on viridis over `window`: the weights of `weights` (a `tcksift2` file, one per
    /// streamline of the file) or, without it, the tractogram's own per-streamline array `name` (a TRX's
    /// `dps`, a `.trk`'s properties). Streamlines whose value is below `min` are not shown (a change rebuilds).
    Value {
        /// A weights file (`tcksift2`), one value per streamline; none: the tractogram's array `name`.
        #[serde(default)]
        weights: Option<PathBuf>,
        /// The tractogram's per-streamline array, used without `weights`.
        #[serde(default)]
        name: String,
        /// The values at viridis' two ends.
        window: (f32, f32),
        /// Streamlines whose value is below this are not shown; none: all are.
        #[serde(default)]
        min: Option<f32>,
    },
    /// A value per point on viridis over `window`: the values of `file` (an MRtrix `.tsf`, as `tcksample`
    /// writes it, one per point of the file's streamlines) or, without it, the tractogram's own per-point array
    /// `name` (a TRX's `dpp`, a `.trk`'s scalars).
    PointValue {
        /// A track scalar file (`.tsf`); none: the tractogram's array `name`.
        #[serde(default)]
        file: Option<PathBuf>,
        /// The tractogram's per-point array, used without `file`.
        #[serde(default)]
        name: String,
        /// The values at viridis' two ends.
        window: (f32, f32),
    },
}

/// Where tracking starts.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Seeds {
    /// Every `spacing`-th voxel along each axis whose FA is at least `min_fa`.
    Grid {
        /// Every `spacing`-th voxel along each axis.
        spacing: usize,
        /// Lowest FA of a seed voxel.
        min_fa: f64,
    },
    /// `per_voxel` seeds in each voxel whose centre lies in the sphere (world mm), spread on a regular
    /// sub-grid.
    Sphere {
        /// The sphere's centre, world mm (RAS+).
        centre: [f32; 3],
        /// The sphere's radius, mm.
        radius: f32,
        /// Seeds in each voxel.
        per_voxel: usize,
    },
}

impl Default for Seeds {
    fn default() -> Self {
        Seeds::Grid { spacing: 2, min_fa: 0.3 }
    }
}

fn default_density_voxel() -> f64 {
    1.0
}

fn default_peak_length() -> f32 {
    0.9
}

/// How tracts are drawn.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum TractMode {
    /// Ray-cast tubelets with elliptical sections (hyperstreamlines).
    #[default]
    Tubes,
    /// The polygon-tube baseline, 16 sides per profile.
    Polygon,
    /// Lines.
    Lines,
}

/// Where tensors come from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum TensorSource {
    /// The built-in phantom's tensors.
    Phantom,
    /// A tensor image (X,Y,Z,6) as `fascicle fit dti` and DIPY write it (lower triangle), or in FSL's or
    /// MRtrix3's element order.
    Nifti {
        /// The tensor image.
        path: PathBuf,
        /// The order of its six elements; default DIPY's.
        #[serde(default)]
        order: TensorOrder,
    },
    /// Tensors fitted (weighted least squares) to a DWI with its `.bval`/`.bvec` beside it (or a `.mif`'s
    /// `dw_scheme`).
    Dwi {
        /// The DWI.
        path: PathBuf,
        /// Frame of the `.bvec` file (default FSL's: x negated on images with a positive determinant).
        #[serde(default)]
        bvecs: BvecConvention,
    },
    /// The seed's synthetic spiral of `n` tensors (`fascicle_core::phantom::spiral`); the slice settings
    /// are ignored and sizes are fractions of 8 mm.
    Spiral {
        /// Tensors along the spiral.
        n: usize,
    },
}

/// Where SH coefficients come from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum ShSource {
    /// CSA ODFs fitted (DIPY's CsaOdfModel, smooth 0.006) to a noiseless multi-tensor DWI of the built-in
    /// phantom (64 directions, b 1000).
    PhantomCsa {
        /// Highest SH order fitted (even).
        l_max: usize,
    },
    /// A coefficient image (X,Y,Z,n) as `fascicle fit csa`, DIPY or MRtrix write it, in `basis` (DIPY's default,
    /// descoteaux07 legacy, when absent).
    Nifti {
        /// The coefficient image.
        path: PathBuf,
        /// The SH basis of its coefficients; default DIPY's (descoteaux07, legacy).
        #[serde(default)]
        basis: ShBasis,
    },
}

/// Where a scalar (or colour) volume comes from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum VolumeSource {
    /// FA of the built-in ring/cross phantom.
    PhantomFa,
    /// A NIfTI file; `volume` picks the 4th-dimension index (0 when absent).
    Nifti {
        /// The image file.
        path: PathBuf,
        /// Index along the 4th dimension; default 0.
        #[serde(default)]
        volume: usize,
    },
    /// A colour image (RGB24, or three volumes of red, green, blue), shown in colour.
    Rgb {
        /// The image file.
        path: PathBuf,
    },
    /// The track-density map of a tract source (streamlines per voxel, each counted once per voxel, as
    /// MRtrix3's `tckmap`) on an axis-aligned grid of `voxel_mm` voxels covering the streamlines.
    Density {
        /// The streamlines counted.
        tracts: TractSource,
        /// Voxel size of the map's grid, mm; default 1.
        #[serde(default = "default_density_voxel")]
        voxel_mm: f64,
    },
}

pub use fascicle_render::layer::SliceAxis;

/// A perspective camera in world (RAS+ mm) coordinates.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct CameraSpec {
    /// The camera's position, world mm; default (-70, -120, 80).
    pub eye: [f32; 3],
    /// The point looked at, world mm; default the origin.
    pub target: [f32; 3],
    /// The camera's up direction, world (RAS+); default +z (superior).
    pub up: [f32; 3],
    /// Vertical field of view in degrees. Defaults to 45.
    pub fov_y_deg: f32,
}

impl CameraSpec {
    /// A camera looking at the box `[lo, hi]` (world mm) from the direction `like` looks from, far enough that
    /// the box's bounding sphere fills about 90 % of the view's height; same up and field of view.
    pub fn framing(lo: glam::DVec3, hi: glam::DVec3, like: &CameraSpec) -> CameraSpec {
        let centre = (lo + hi) / 2.0;
        let radius = ((hi - lo).length() / 2.0).max(1.0);
        let from = (glam::Vec3::from(like.eye) - glam::Vec3::from(like.target)).as_dvec3().normalize_or(glam::DVec3::Z);
        let half_fov = (f64::from(like.fov_y_deg.clamp(1.0, 170.0)) / 2.0).to_radians();
        let distance = radius / half_fov.sin() / 0.9;
        CameraSpec {
            eye: (centre + from * distance).as_vec3().to_array(),
            target: centre.as_vec3().to_array(),
            ..*like
        }
    }
}

/// Points of a tractogram that [`file_bounds`] reads: 4M (48 MB of a `.tck`).
pub const FRAMING_POINTS: usize = 4_000_000;

/// The world bounds (RAS+ mm) of a data file: a NIfTI image's voxel grid through its affine (from the header
/// alone), an MRtrix image's, a TRX's reference grid, or the points of a tractogram's first streamlines (up to
/// [`FRAMING_POINTS`]: all of any tractogram under 4M points). `None` when the file cannot be read or holds
/// nothing.
pub fn file_bounds(path: &Path) -> Option<(glam::DVec3, glam::DVec3)> {
    let lower = path.to_string_lossy().to_ascii_lowercase();
    let mut lo = glam::DVec3::splat(f64::INFINITY);
    let mut hi = glam::DVec3::splat(f64::NEG_INFINITY);
    let grid = if fascicle_core::io::mif::is_mif(path) {
        // An MRtrix header is text of unknown length: the image is read (and the layer reads it again, cached).
        let v = fascicle_core::io::mif::read_image::<f32>(path).ok()?;
        Some((v.shape, v.world_from_voxel))
    } else if lower.ends_with(".nii") || lower.ends_with(".nii.gz") {
        fascicle_core::io::nifti::read_header(path).ok().map(|h| (h.shape, h.world_from_voxel))
    } else if lower.ends_with(".trx") {
        // A TRX frames its reference grid (its header only: the positions are not read); without one, its points.
        let reader = fascicle_core::io::stream::TractogramReader::open(path).ok()?;
        let h = reader.header().trx.as_ref().filter(|h| h.dims.iter().all(|d| *d > 1));
        h.map(|h| (h.dims.to_vec(), h.voxel_to_rasmm))
    } else {
        None
    };
    if let Some((shape, world_from_voxel)) = grid {
        let d = [0, 1, 2].map(|i| shape.get(i).copied().unwrap_or(1) as f64 - 1.0);
        for k in 0..8 {
            let v = glam::DVec3::new(
                if k & 1 == 0 { 0.0 } else { d[0] },
                if k & 2 == 0 { 0.0 } else { d[1] },
                if k & 4 == 0 { 0.0 } else { d[2] },
            );
            let p = world_from_voxel.transform_point3(v);
            (lo, hi) = (lo.min(p), hi.max(p));
        }
    } else {
        // The points of the first streamlines, up to FRAMING_POINTS: a whole tractogram is gigabytes, and reading
        // all of it to place the camera kept the window from opening (7-26 s for 10M streamlines, 12 GB). Seeds
        // spread over the brain make the first streamlines a sample of the whole.
        let mut reader = fascicle_core::io::stream::TractogramReader::open(path).ok()?;
        let mut seen = 0;
        while seen < FRAMING_POINTS
            && let Some(t) = reader.next_chunk(FRAMING_POINTS - seen).ok()?
            && !t.points.is_empty()
        {
            for p in t.points.iter().filter(|p| p.is_finite()) {
                (lo, hi) = (lo.min(p.as_dvec3()), hi.max(p.as_dvec3()));
            }
            seen += t.points.len();
        }
    }
    (lo.is_finite() && hi.is_finite()).then_some((lo, hi))
}

impl Default for CameraSpec {
    fn default() -> Self {
        Self { eye: [-70.0, -120.0, 80.0], target: [0.0, 0.0, 0.0], up: [0.0, 0.0, 1.0], fov_y_deg: 45.0 }
    }
}

impl Scene {
    /// The phantom's FA in three orthogonal slices, with axes.
    pub fn default_scene() -> Self {
        let slice = |name: &str, axis| LayerSpec {
            name: name.into(),
            visible: true,
            opacity: 1.0,
            kind: LayerKind::Slice { source: VolumeSource::PhantomFa, axis, index: None, window: None },
        };
        Self {
            layers: vec![
                slice("FA axial", SliceAxis::Z),
                LayerSpec {
                    name: "Tensor splats (coronal slab)".into(),
                    visible: true,
                    opacity: 1.0,
                    kind: LayerKind::TensorSplats {
                        source: TensorSource::Phantom,
                        axis: SliceAxis::Y,
                        index: None,
                        thickness: 3,
                        size: 0.5,
                        min_fa: 0.0,
                        render: SplatSettings::default(),
                    },
                },
                LayerSpec {
                    name: "ODF glyphs (CSA)".into(),
                    visible: true,
                    opacity: 1.0,
                    kind: LayerKind::ShGlyphs {
                        source: ShSource::PhantomCsa { l_max: 6 },
                        axis: SliceAxis::Z,
                        index: None,
                        spacing: 2,
                        plane: None,
                        sampling: Sampling::Nearest,
                        full_volume: false,
                        // Sized to the grid, one scale for the layer: fibre lobes stand out from the round
                        // background.
                        style: GlyphStyle {
                            fit_lobes: true,
                            cell_fill: Some(0.9),
                            normalise: fascicle_core::sh::glyph::Normalise::Global,
                            ..GlyphStyle::default()
                        },
                        render: RayCastSettings::default(),
                    },
                },
                LayerSpec {
                    name: "Hyperstreamlines (RK4)".into(),
                    visible: true,
                    opacity: 1.0,
                    kind: LayerKind::Tracts {
                        source: TractSource::PhantomRk4 { seed_spacing: 4 },
                        mode: TractMode::Tubes,
                        render: TubeSettings::default(),
                        // The ring tracts through the top of the ring (radius 24-32 mm); the crossing bundle is out.
                        rois: vec![Roi {
                            shape: RoiShape::Sphere { centre: [0.0, 28.0, 1.0], radius: 4.0 },
                            mode: RoiMode::Include,
                        }],
                        masks: vec![],
                        ends_only: false,
                        deleted: vec![],
                        colouring: Default::default(),
                    },
                },
                LayerSpec {
                    name: "FA volume (DVR)".into(),
                    visible: true,
                    opacity: 1.0,
                    kind: LayerKind::Volume { source: VolumeSource::PhantomFa, render: faint_context() },
                },
                LayerSpec {
                    name: "Axes".into(),
                    visible: true,
                    opacity: 1.0,
                    kind: LayerKind::Axes { length_mm: 30.0 },
                },
            ],
            // Closer than the default camera: the phantom fills the view.
            camera: CameraSpec { eye: [-45.0, -80.0, 55.0], ..CameraSpec::default() },
            views: Default::default(),
        }
    }

    /// Reads a scene file (RON); the message names the file and what is wrong.
    pub fn load(path: &Path) -> Result<Self, String> {
        let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
        ron::from_str(&text).map_err(|e| format!("{}: not a scene file: {e}", path.display()))
    }

    /// Writes the scene to `path` as pretty-printed RON.
    pub fn save(&self, path: &Path) -> Result<(), String> {
        let text = ron::ser::to_string_pretty(self, ron::ser::PrettyConfig::default()).map_err(|e| e.to_string())?;
        std::fs::write(path, text).map_err(|e| format!("{}: {e}", path.display()))
    }

    /// Opens a file into this scene: a scene file (.ron) replaces it, a data file adds a layer.
    pub fn open_file(&mut self, path: &Path) -> Result<(), String> {
        if path.extension().is_some_and(|e| e == "ron") {
            *self = Scene::load(path)?;
        } else {
            self.layers.push(Scene::layer_for_file(path)?);
            // Frame the new data: files from scanners sit far from the origin.
            if let Some((lo, hi)) = file_bounds(path) {
                self.camera = CameraSpec::framing(lo, hi, &self.camera);
            }
        }
        Ok(())
    }

    /// A layer for a data file, by what it holds ([`fascicle_core::io::classify`] for images): SH glyphs in the
    /// recorded basis, tensor glyphs in the file's element order, peaks as lines, RGB maps in colour, DWIs and
    /// scalar maps as a slice, tractograms as lines. Where the content is ambiguous this is the likeliest; see
    /// [`Scene::layer_choices`].
    pub fn layer_for_file(path: &Path) -> Result<LayerSpec, String> {
        Ok(Scene::layer_choices(path)?.0)
    }

    /// The layer for a data file and, when its content is ambiguous, the other ways to open it (for the
    /// viewer to ask).
    pub fn layer_choices(path: &Path) -> Result<(LayerSpec, Vec<LayerSpec>), String> {
        if !path.is_file() {
            return Err(format!("{}: no such file", path.display()));
        }
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let lower = name.to_ascii_lowercase();
        let spec = |kind| LayerSpec { name: name.clone(), visible: true, opacity: 1.0, kind };
        if [".nii", ".nii.gz", ".mif", ".mif.gz"].iter().any(|e| lower.ends_with(e)) {
            let c = fascicle_core::io::classify::classify(path).map_err(|e| e.to_string())?;
            let others = c.ambiguous.iter().filter(|k| **k != c.kind).map(|k| spec(layer_kind_for(path, k))).collect();
            return Ok((spec(layer_kind_for(path, &c.kind)), others));
        }
        if [".trk", ".tck", ".trk.gz", ".tck.gz", ".trx"].iter().any(|e| lower.ends_with(e)) {
            return Ok((spec(LayerKind::Tractogram { path: path.to_path_buf() }), vec![]));
        }
        Err(format!("{}: not a NIfTI or MRtrix image, tractogram or scene file", path.display()))
    }
}

/// How an image of `kind` opens.
pub fn layer_kind_for(path: &Path, kind: &ImageKind) -> LayerKind {
    let path = path.to_path_buf();
    match kind {
        ImageKind::Peaks => LayerKind::Tracts {
            source: TractSource::Peaks { path, length: default_peak_length() },
            mode: TractMode::Lines,
            render: Default::default(),
            rois: Vec::new(),
            masks: vec![],
            ends_only: false,
            deleted: vec![],
            colouring: Default::default(),
        },
        ImageKind::Sh { basis, .. } => LayerKind::ShGlyphs {
            source: ShSource::Nifti { path, basis: basis.unwrap_or_default() },
            axis: SliceAxis::Z,
            index: None,
            spacing: 1,
            plane: None,
            sampling: Sampling::Nearest,
            full_volume: false,
            // Sized to the grid, as mrview and FURY do.
            style: GlyphStyle { fit_lobes: true, cell_fill: Some(0.9), ..GlyphStyle::default() },
            render: RayCastSettings::default(),
        },
        ImageKind::Tensor { order } => LayerKind::TensorGlyphs {
            source: TensorSource::Nifti { path, order: *order },
            axis: SliceAxis::Z,
            index: None,
            spacing: 1,
            size: glyph_size(),
            min_fa: 0.0,
            render: TensorGlyphSettings::default(),
        },
        ImageKind::Rgb => {
            LayerKind::Slice { source: VolumeSource::Rgb { path }, axis: SliceAxis::Z, index: None, window: None }
        }
        // A DWI shows its first volume (a b0); tensors fitted to it are a layer the panel adds.
        ImageKind::Dwi { .. } | ImageKind::Scalar | ImageKind::Series => LayerKind::Slice {
            source: VolumeSource::Nifti { path, volume: 0 },
            axis: SliceAxis::Z,
            index: None,
            window: None,
        },
    }
}

/// The tensor source for a file: tensors fitted to it when it is a DWI, else its tensors in the element
/// order its content shows (DIPY's when it cannot be read).
pub fn tensor_source_for(path: &Path) -> TensorSource {
    match fascicle_core::io::classify::classify(path).map(|c| c.kind) {
        Ok(ImageKind::Dwi { .. }) => TensorSource::Dwi { path: path.to_path_buf(), bvecs: BvecConvention::default() },
        Ok(ImageKind::Tensor { order }) => TensorSource::Nifti { path: path.to_path_buf(), order },
        _ => TensorSource::Nifti { path: path.to_path_buf(), order: TensorOrder::default() },
    }
}

/// The default scene's volume: the default FA transfer function at a fifth of its opacity, a haze that leaves
/// the glyphs and tubes inside it visible.
fn faint_context() -> VolumeSettings {
    let mut v = VolumeSettings::default();
    for p in &mut v.tf.points {
        p.rgba[3] *= 0.2;
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Files open by what they hold: a 6-volume tensor image as tensor glyphs (not l_max 2 SH), an SH image
    /// as glyphs in the basis its header records, a DWI (bval/bvec beside) as a slice, a tractogram as lines.
    #[test]
    fn files_open_by_their_content() {
        let data = crate::repo_path("data");
        let kind = |p: &str| Scene::layer_for_file(&data.join(p)).unwrap().kind;
        assert!(
            matches!(
                kind("dti/small_64D_tensor.nii.gz"),
                LayerKind::TensorGlyphs { source: TensorSource::Nifti { order: TensorOrder::Dipy, .. }, .. }
            ),
            "{:?}",
            kind("dti/small_64D_tensor.nii.gz")
        );
        let LayerKind::ShGlyphs { source: ShSource::Nifti { basis, .. }, .. } = kind("sh/small_64D_csa_l6.nii.gz")
        else {
            panic!()
        };
        assert_eq!(
            Some(basis),
            fascicle_core::sh::recorded_basis(
                &fascicle_core::io::nifti::read_header(data.join("sh/small_64D_csa_l6.nii.gz")).unwrap().descrip
            )
        );
        assert!(matches!(kind("sh/func_coef.nii.gz"), LayerKind::ShGlyphs { .. }));
        assert!(matches!(
            kind("dwi/small_64D.nii"),
            LayerKind::Slice { source: VolumeSource::Nifti { volume: 0, .. }, .. }
        ));
        assert!(matches!(kind("dti/small_64D_fa.nii.gz"), LayerKind::Slice { .. }));
        assert!(matches!(kind("tracts/tracks300.trk"), LayerKind::Tractogram { .. }));
        assert_eq!(
            tensor_source_for(&data.join("dwi/small_64D.nii")),
            TensorSource::Dwi { path: data.join("dwi/small_64D.nii"), bvecs: BvecConvention::Fsl }
        );
    }

    /// A tractogram frames the camera by its first streamlines' points (up to FRAMING_POINTS): a small file by
    /// all of them (as `fascicle info` bounds them), a large one without reading past the sample, so a far
    /// streamline at its end does not count.
    #[test]
    fn tractograms_are_framed_by_their_first_points() {
        use fascicle_core::io::Tractogram;
        let trk = crate::repo_path("data/tracts/tracks300.trk");
        let t = Tractogram::read(&trk).unwrap();
        let (lo, hi) = t
            .points
            .iter()
            .fold((glam::Vec3::splat(f32::MAX), glam::Vec3::splat(f32::MIN)), |(a, b), p| (a.min(*p), b.max(*p)));
        assert_eq!(file_bounds(&trk), Some((lo.as_dvec3(), hi.as_dvec3())));

        let mut big = Tractogram::new();
        let line: Vec<glam::Vec3> = (0..1000).map(|i| glam::Vec3::new(i as f32 * 0.05, 1.0, 2.0)).collect();
        for _ in 0..FRAMING_POINTS / 1000 + 10 {
            big.push(&line);
        }
        big.push(&[glam::Vec3::splat(1000.0), glam::Vec3::splat(1001.0)]);
        let tmp_path = tempfile::tempdir().unwrap();
        let path = tmp_path.path().join("fascicle-framing.tck");
        fascicle_core::io::tck::write(&path, &big, &[]).unwrap();
        let bounds = file_bounds(&path);
        std::fs::remove_file(&path).ok();
        let want = (glam::DVec3::new(0.0, 1.0, 2.0), glam::DVec3::new(999.0 * 0.05f32 as f64, 1.0, 2.0));
        let (a, b) = bounds.expect("bounds");
        assert!(a == want.0 && (b - want.1).length() < 1e-4, "{a} {b}");
    }

    /// An MRtrix image frames the camera as its NIfTI does: the same voxel grid in scanner space.
    #[test]
    fn mif_images_have_the_bounds_of_their_nifti() {
        let nii = crate::repo_path("data/dti/small_64D_fa.nii.gz");
        let (v, _) = fascicle_core::io::nifti::read::<f32>(&nii).unwrap();
        let tmp_mif = tempfile::tempdir().unwrap();
        let mif = tmp_mif.path().join("fascicle-bounds.mif");
        fascicle_core::io::mif::write(&mif, &v, &[]).unwrap();
        let (a, b) = (file_bounds(&nii).unwrap(), file_bounds(&mif).unwrap());
        assert!((a.0 - b.0).abs().max_element() < 1e-5 && (a.1 - b.1).abs().max_element() < 1e-5, "{a:?} {b:?}");
        std::fs::remove_file(mif).ok();
    }

    /// The example scene of the four-view layout loads with its views, and a scene without views has the
    /// 3D view alone, with colour bars.
    #[test]
    fn scene_files_carry_their_views() {
        let s = Scene::load(&crate::repo_path("scenes/ortho.ron")).unwrap();
        assert!(s.views.ortho && s.views.follow && s.views.colour_bars);
        assert_eq!(s.views.crosshair, Some([5.0, -8.0, 2.0]));
        let plain = Scene::load(&crate::repo_path("scenes/spiral50.ron")).unwrap();
        assert_eq!(plain.views, fascicle_views::Views::default());
        assert!(!plain.views.ortho && plain.views.colour_bars);
    }

    /// A scene sets only what it changes: every settings struct and layer field has a default.
    #[test]
    fn minimal_scenes_load_with_defaults() {
        let text = r#"(layers: [
            (name: "odf", kind: ShGlyphs(source: PhantomCsa(l_max: 4), style: (scale: 3.0))),
            (name: "splats", kind: TensorSplats(source: Phantom, render: (opacity: 0.5))),
            (name: "fa", kind: Slice(source: PhantomFa)),
            (name: "dvr", kind: Volume(source: PhantomFa, render: (step: 0.5))),
            (name: "tracts", kind: Tracts(source: PhantomRk4(seed_spacing: 4), render: (scale: 2.0))),
            (name: "glyphs", kind: TensorGlyphs(source: Phantom)),
        ])"#;
        let scene: Scene = ron::from_str(text).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(scene.camera, CameraSpec::default());
        let LayerKind::ShGlyphs { style, render, axis, index, spacing, .. } = &scene.layers[0].kind else {
            panic!("{:?}", scene.layers[0].kind)
        };
        assert_eq!(style.scale, 3.0);
        assert_eq!(GlyphStyle { scale: 3.0, ..*style }, GlyphStyle { scale: 3.0, ..GlyphStyle::default() });
        assert_eq!((*render, *axis, *index, *spacing), (RayCastSettings::default(), SliceAxis::Z, None, 1));
        let LayerKind::TensorSplats { render, .. } = &scene.layers[1].kind else { panic!() };
        assert_eq!(*render, SplatSettings { opacity: 0.5, ..SplatSettings::default() });
        assert!(scene.layers.iter().all(|l| l.visible && l.opacity == 1.0));
    }
}
