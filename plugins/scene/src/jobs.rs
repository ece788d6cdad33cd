//! What a layer shows, computed off the main thread: [`build`] turns a layer's structure (its sources and
//! what it selects) into [`Content`], CPU data ready to upload, reading files and fitting models through the
//! [`DataCache`]. Jobs report their stage and progress in a [`JobProgress`] and stop at the next check once
//! cancelled.

use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use bevy::math::Vec3;
use fascicle_core::Volume;
use fascicle_core::dti::glyph::TensorGlyph;
use fascicle_core::dti::splat::Splat;
use fascicle_core::io::Tractogram;
use fascicle_core::sh::glyph::{Glyph, GlyphPlane, GlyphStyle, Sampling, make_glyphs, sample_plane};
use fascicle_core::sh::{self, OdfKind, OdfModel, ShBasis};
use fascicle_sh_glyphs::{Selection, ShField, ShFieldSettings, field_glyphs};
use fascicle_tensors::layer::{field_splats, field_tensor_glyphs};
use fascicle_tensors::{SplatShape, TensorField, TensorGlyphShape};

use crate::cache::DataCache;
use crate::model::{
    LayerKind, MaskRoi, ShSource, SliceAxis, TensorSource, TractColouring, TractMode, TractSource, VolumeSource,
};
use fascicle_tracts::{LineDetail, PreparedTracts};
use fascicle_views::{Channels, auto_window};

/// A job's stage, progress and cancel flag, shared between the job and the panel that shows it, and the parts
/// of its content it has delivered so far ([`Content::Streamed`]).
#[derive(Debug, Default)]
pub struct JobProgress {
    stage: Mutex<&'static str>,
    done: AtomicUsize,
    total: AtomicUsize,
    cancelled: AtomicBool,
    /// Content delivered while the job runs, for the main thread to show as it comes ([`Content::Streamed`]).
    pub parts: Parts,
    /// The voxel grid the content comes from, once read (the crosshair's voxel on it).
    grid: Mutex<Option<fascicle_views::VoxelGrid>>,
    /// A tract layer's values per streamline or per point (all of them, before any threshold or mask), once read.
    values: Mutex<Option<Arc<ValueHistogram>>>,
}

/// Bins of a [`ValueHistogram`].
pub const VALUE_BINS: usize = 64;

/// How a tract layer's values per streamline (`tcksift2` weights, a TRX's or `.trk`'s per-streamline array) are
/// distributed, for its panel: [`VALUE_BINS`] equal bins between the lowest and highest finite value.
#[derive(Clone, Debug, PartialEq)]
pub struct ValueHistogram {
    /// The lowest and highest finite value (both 0 when there is none).
    pub range: (f32, f32),
    /// Streamlines per bin, [`VALUE_BINS`] bins over `range` (the highest value in the last); non-finite values
    /// are not counted.
    pub counts: Vec<u32>,
}

impl ValueHistogram {
    /// The histogram of `values`.
    pub fn of(values: &[f32]) -> Self {
        let finite = || values.iter().copied().filter(|v| v.is_finite());
        let (lo, hi) = finite().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)));
        let mut counts = vec![0u32; VALUE_BINS];
        if lo > hi {
            return Self { range: (0.0, 0.0), counts };
        }
        let span = f64::from(hi) - f64::from(lo);
        for v in finite() {
            let at = if span > 0.0 { (f64::from(v) - f64::from(lo)) / span } else { 0.0 };
            counts[((at * VALUE_BINS as f64) as usize).min(VALUE_BINS - 1)] += 1;
        }
        Self { range: (lo, hi), counts }
    }
}

/// Parts of a layer's content that its job delivers while it runs, oldest first: streamlines as they are
/// tracked, or a large tractogram in parts of at most [`PART_POINTS`] points (a streamed file's later parts
/// larger: [`grown_part_points`]), so that the main thread uploads them a few at a time and never stalls on one
/// large upload.
#[derive(Default)]
pub struct Parts(Mutex<std::collections::VecDeque<Content>>);

impl std::fmt::Debug for Parts {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Parts({} waiting)", self.len())
    }
}

impl Parts {
    fn lock(&self) -> std::sync::MutexGuard<'_, std::collections::VecDeque<Content>> {
        self.0.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Delivers `part`, after those waiting.
    pub fn push(&self, part: Content) {
        self.lock().push_back(part);
    }

    /// The oldest part not yet taken.
    pub fn pop(&self) -> Option<Content> {
        self.lock().pop_front()
    }

    /// Number of parts waiting.
    pub fn len(&self) -> usize {
        self.lock().len()
    }

    /// Whether no part is waiting.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// The most glyphs of one delivered part of an SH glyph layer (one entity each: 4,096 spawn and upload in
/// about 27 ms on this project's 2-core reference machine).
pub const GLYPH_PART: usize = 4096;

/// The most points of one delivered part of a tract layer, and of a streamed file's first parts (later ones
/// grow: [`grown_part_points`]) (lines: about 2 vertices per point; 250k points upload in about 20 ms on this
/// project's 2-core reference machine).
pub const PART_POINTS: usize = 250_000;

/// The error a cancelled job ends with.
pub const CANCELLED: &str = "cancelled";

impl JobProgress {
    /// Records the voxel grid the layer's content is cut from.
    pub fn set_grid(&self, grid: fascicle_views::VoxelGrid) {
        *self.grid.lock().unwrap_or_else(|e| e.into_inner()) = Some(grid);
    }

    /// The voxel grid the content is cut from, once the job has read it.
    pub fn grid(&self) -> Option<fascicle_views::VoxelGrid> {
        *self.grid.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Records how the layer's values (per streamline or per point) are distributed.
    pub fn set_values(&self, values: ValueHistogram) {
        *self.values.lock().unwrap_or_else(|e| e.into_inner()) = Some(Arc::new(values));
    }

    /// How the layer's values per streamline are distributed, once the job has read them.
    pub fn values(&self) -> Option<Arc<ValueHistogram>> {
        self.values.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// Starts a stage of `total` units (0: unknown); fails when the job was cancelled.
    pub fn stage(&self, name: &'static str, total: usize) -> Result<(), String> {
        if self.is_cancelled() {
            return Err(CANCELLED.into());
        }
        *self.stage.lock().unwrap_or_else(|e| e.into_inner()) = name;
        self.done.store(0, Ordering::Relaxed);
        self.total.store(total, Ordering::Relaxed);
        Ok(())
    }

    /// `n` more units of the current stage done (from any thread).
    pub fn advance(&self, n: usize) {
        self.done.fetch_add(n, Ordering::Relaxed);
    }

    /// The current stage and, when its size is known, the fraction done.
    pub fn snapshot(&self) -> (&'static str, Option<f32>) {
        let stage = *self.stage.lock().unwrap_or_else(|e| e.into_inner());
        let total = self.total.load(Ordering::Relaxed);
        let done = self.done.load(Ordering::Relaxed);
        (stage, (total > 0).then(|| (done as f32 / total as f32).min(1.0)))
    }

    /// Asks the job to stop: its next stage check fails with [`CANCELLED`].
    pub fn cancel(&self) {
        self.cancelled.store(true, Ordering::Relaxed);
    }

    /// Whether the job was cancelled.
    pub fn is_cancelled(&self) -> bool {
        self.cancelled.load(Ordering::Relaxed)
    }
}

/// A layer's CPU-side content, ready for the main thread to upload.
pub enum Content {
    /// Placed glyphs and their voxels, shared with the cache.
    ShGlyphs(Arc<Vec<Glyph>>, Arc<Vec<[u32; 3]>>),
    /// Tensor glyphs of a slice (or of the spiral phantom).
    TensorGlyphs {
        /// The glyphs, in the world frame.
        glyphs: Vec<TensorGlyph>,
        /// Each glyph's voxel (indices; a spiral glyph's number as `[i, 0, 0]`), in the same order.
        voxels: Vec<[u32; 3]>,
    },
    /// Colour and opacity unset: the layer's colouring is applied at upload.
    Splats(Vec<Splat>),
    /// Streamlines with their segment grid and geometry built (as the layer's mode draws them).
    Tracts(fascicle_tracts::PreparedTracts),
    /// A scalar volume (a volume layer of the volume plugin: it makes the texture).
    Volume {
        /// The scalar volume, shared with the cache.
        volume: Arc<Volume<f32>>,
    },
    /// An image to slice (a slice layer: the views plugin cuts its slices).
    Slice {
        /// The image, shared with the cache.
        volume: Arc<Volume<f32>>,
        /// The volumes shown.
        channels: Channels,
        /// The window shown when the layer sets none (found here, off the main thread).
        auto_window: (f32, f32),
    },
    /// The world axes from the origin: X red, Y green, Z blue.
    Axes {
        /// Length of each axis (mm).
        length_mm: f32,
    },
    /// Everything went through the job's [`JobProgress::parts`] (each a `Tracts` part) while it ran;
    /// `items` in all.
    Streamed {
        /// Items delivered in all (as [`Content::items`] counts them).
        items: usize,
    },
}

impl Content {
    /// Items it holds (glyphs, splats, streamlines, voxels), for the layer's status.
    pub fn items(&self) -> usize {
        match self {
            Content::ShGlyphs(glyphs, _) => glyphs.len(),
            Content::TensorGlyphs { glyphs, .. } => glyphs.len(),
            Content::Splats(s) => s.len(),
            Content::Tracts(t) => t.n_streamlines,
            Content::Volume { volume, .. } => volume.n_voxels(),
            Content::Slice { volume, .. } => volume.n_voxels(),
            Content::Axes { .. } => 3,
            Content::Streamed { items } => *items,
        }
    }
}

/// Streamlines and, when the source has them, per-point world tensors (hyperstreamline sections).
#[derive(Clone)]
pub struct TractData {
    /// The streamlines (world RAS+ mm).
    pub tractogram: Arc<Tractogram>,
    /// One world-frame tensor per point of `tractogram` (lower-triangular), when the source has them.
    pub tensors: Option<Arc<Vec<[f32; 6]>>>,
}

/// The content of a layer of kind `kind` (its structure: draw settings are applied at upload).
pub fn build(kind: &LayerKind, cache: &DataCache, progress: &JobProgress) -> Result<Content, String> {
    match kind {
        LayerKind::ShGlyphs { source, axis, index, spacing, plane, sampling, full_volume, style, .. } => {
            let field = sh_field(cache, source, progress)?;
            progress.set_grid(fascicle_views::VoxelGrid::of(&field.coeffs));
            // Placed glyphs are kept too (keyed by the layer's structure): stepping back to a slice, or onto
            // one that was prefetched (`prefetch_neighbours`), costs a copy.
            // A slice given as "the middle one" is keyed by its index, as its neighbours are.
            let mut key_kind = kind.structure();
            if let LayerKind::ShGlyphs { index: k @ None, axis, .. } = &mut key_kind {
                *k = Some(field.coeffs.dims3()[axis.index()] / 2);
            }
            let placed = cache.get_or_load(
                &format!("glyphs:{key_kind:?}"),
                &source_files(source),
                |(g, _): &(Arc<Vec<Glyph>>, Arc<Vec<[u32; 3]>>)| g.iter().map(|g| 96 + 8 * g.coeffs.len()).sum(),
                || {
                    progress.stage("placing glyphs", 0)?;
                    match plane {
                        _ if *full_volume => field_glyphs(&field, &Selection::Volume { spacing: *spacing }, *style),
                        Some(p) => plane_glyphs(&field, p, *sampling, *style),
                        None => field_glyphs(
                            &field,
                            &Selection::Slice { axis: *axis, index: *index, spacing: *spacing },
                            *style,
                        ),
                    }
                    .map(|(glyphs, voxels)| (Arc::new(glyphs), Arc::new(voxels)))
                },
            )?;
            let (glyphs, voxels) = &*placed;
            if glyphs.len() <= GLYPH_PART {
                // Shared with the cache, not copied.
                return Ok(Content::ShGlyphs(glyphs.clone(), voxels.clone()));
            }
            // One entity per glyph: a large slice goes in parts, a part per frame.
            for (k, part) in glyphs.chunks(GLYPH_PART).enumerate() {
                let vox = voxels.get(k * GLYPH_PART..(k * GLYPH_PART + part.len()).min(voxels.len()));
                let vox = vox.unwrap_or_default().to_vec();
                progress.parts.push(Content::ShGlyphs(Arc::new(part.to_vec()), Arc::new(vox)));
            }
            Ok(Content::Streamed { items: glyphs.len() })
        }
        LayerKind::TensorGlyphs { source, axis, index, spacing, size, min_fa, .. } => {
            let (glyphs, voxels) = tensor_glyphs(cache, source, *axis, *index, *spacing, *size, *min_fa, progress)?;
            Ok(Content::TensorGlyphs { glyphs, voxels })
        }
        LayerKind::TensorSplats { source, axis, index, thickness, size, min_fa, .. } => {
            Ok(Content::Splats(slab_splats(cache, source, *axis, *index, *thickness, *size, *min_fa, progress)?))
        }
        LayerKind::Tracts { source, mode, render, colouring, masks, .. } => {
            // A scalar image to colour by is read (through the cache) before any part is made.
            let scalar = match colouring {
                TractColouring::Scalar { source, .. } => Some(scalar_volume(cache, source, progress)?),
                _ => None,
            };
            let prepare = |part: TractData, first: usize, values: Option<TractValues>, detail: LineDetail| {
                let n = part.tractogram.n_streamlines();
                let part_values = values.map(|v| match v {
                    TractValues::Streamlines(v) => TractValues::Streamlines(&v[first..first + n]),
                    TractValues::Points { values, offsets } => {
                        TractValues::Points { values, offsets: &offsets[first..first + n] }
                    }
                });
                let colours = point_colours(colouring, &part.tractogram, scalar.as_deref(), part_values);
                let colour = colours.as_deref();
                let (t, tensors) = (part.tractogram, part.tensors.as_deref().map(|v| v.as_slice()));
                let prepared = match mode {
                    TractMode::Tubes => PreparedTracts::tubes_coloured(t, tensors, render, colour),
                    TractMode::Polygon => PreparedTracts::polygon_tubes(t, tensors, render.scale),
                    TractMode::Lines => PreparedTracts::lines_in_detail(t, colour, detail),
                };
                // No index is built here: a layer's job is given no ROIs (they re-select in place,
                // `LayerKind::structure`); its sets queue their indexes for the tract plugin's background
                // builder when an ROI or a pick first needs one.
                Content::Tracts(prepared.starting_at(first))
            };
            // Tracking delivers its streamlines as they are computed.
            let streamed = AtomicBool::new(false);
            let by_value = matches!(colouring, TractColouring::Value { .. } | TractColouring::PointValue { .. });
            if by_value && matches!(source, TractSource::Track { .. }) {
                return Err(
                    "colouring by values per streamline or per point needs a file's streamlines, not tracking".into()
                );
            }
            // Parts delivered as they come are numbered in order (the layer's index of their first streamline).
            let delivered = std::sync::atomic::AtomicUsize::new(0);
            let on_part = |part: TractData| {
                streamed.store(true, Ordering::Relaxed);
                let first = delivered.fetch_add(part.tractogram.n_streamlines(), Ordering::Relaxed);
                progress.parts.push(prepare(part, first, None, LineDetail::default()));
            };
            // Cutting masks and values need the whole tractogram: it is not shown in parts as it comes.
            // (Include and exclude masks select among the streamlines built: `mask_regions`.)
            let whole = by_value || masks.iter().any(|m| m.crop);
            // A file without tensors is read in parts, never whole (nor cached whole).
            if let (TractSource::File { path, tensors: None }, false) = (source, whole) {
                return stream_tract_file(path, progress, &|part, first, detail| prepare(part, first, None, detail));
            }
            let mut data = tract_data_in_parts(cache, source, progress, (!whole).then_some(&on_part as OnPart))?;
            let mut keep: Option<Vec<bool>> = None;
            // Values to colour by, aligned with the streamlines (those below a minimum hidden) or their points.
            let (mut per_streamline, mut per_point) = (None, None);
            match colouring {
                TractColouring::Value { weights, name, min, .. } => {
                    let v = streamline_values(&data.tractogram, weights.as_deref(), name)?;
                    progress.set_values(ValueHistogram::of(&v));
                    if let Some(m) = min {
                        let k = keep.get_or_insert_with(|| vec![true; v.len()]);
                        k.iter_mut().zip(&v).for_each(|(k, x)| *k &= x >= m);
                    }
                    per_streamline = Some(match &keep {
                        Some(k) => v.iter().zip(k).filter(|(_, k)| **k).map(|(x, _)| *x).collect(),
                        None => v,
                    });
                }
                TractColouring::PointValue { file, name, .. } => {
                    let v = point_values(&data.tractogram, file.as_deref(), name)?;
                    progress.set_values(ValueHistogram::of(&v));
                    per_point = Some(match &keep {
                        Some(k) => {
                            let t = &data.tractogram;
                            (0..t.n_streamlines())
                                .filter(|s| k[*s])
                                .flat_map(|s| &v[t.offsets[s]..t.offsets[s + 1]])
                                .copied()
                                .collect()
                        }
                        None => v,
                    });
                }
                _ => {}
            }
            if let Some(k) = &keep {
                data = subset_of(&data, k);
            }
            // Cutting masks (tckedit -mask) cut what the other regions kept; a piece takes its streamline's
            // value (as tckedit's pieces keep their streamline's weight) or its own points' values.
            let uncut = data.tractogram.clone();
            let pieces;
            (data, pieces) = cut_by_masks(cache, masks, data, progress)?;
            if let Some(pieces) = &pieces {
                if let Some(v) = &mut per_streamline {
                    *v = pieces.iter().map(|(s, _)| v[*s]).collect();
                }
                if let Some(v) = &mut per_point {
                    let of = |(s, r): &(usize, std::ops::Range<usize>)| {
                        &v[uncut.offsets[*s] + r.start..uncut.offsets[*s] + r.end]
                    };
                    *v = pieces.iter().flat_map(of).copied().collect();
                }
            }
            // The whole (kept) tractogram's offsets locate each streamline's values in every part.
            let whole_tracts = data.tractogram.clone();
            let values = match (&per_streamline, &per_point) {
                (Some(v), _) => Some(TractValues::Streamlines(v)),
                (_, Some(values)) => Some(TractValues::Points { values, offsets: &whole_tracts.offsets }),
                _ => None,
            };
            progress.stage("building the geometry", 0)?;
            let items = data.tractogram.n_streamlines();
            if streamed.load(Ordering::Relaxed) {
                return Ok(Content::Streamed { items });
            }
            let detail = LineDetail::for_points(data.tractogram.points.len() as u64);
            if data.tractogram.points.len() <= PART_POINTS {
                return Ok(prepare(data, 0, values, detail));
            }
            let mut first = 0;
            for part in split(&data, PART_POINTS) {
                progress.stage("building the geometry", 0)?;
                let n = part.tractogram.n_streamlines();
                progress.parts.push(prepare(part, first, values, detail));
                first += n;
            }
            Ok(Content::Streamed { items })
        }
        LayerKind::Volume { source, .. } => {
            let volume = scalar_volume(cache, source, progress)?;
            progress.stage("making the texture", 0)?;
            Ok(Content::Volume { volume })
        }
        LayerKind::Slice { source, .. } => {
            let (vol, channel, window) = match source {
                VolumeSource::PhantomFa => (phantom_fa(cache)?, Channels::One(0), Some((0.0, 1.0))),
                VolumeSource::Nifti { path, volume } => {
                    (image_with_volume(cache, path, *volume, progress)?, Channels::One(*volume), None)
                }
                VolumeSource::Rgb { path } => (image_with_volume(cache, path, 2, progress)?, Channels::Rgb, None),
                VolumeSource::Density { .. } => (scalar_volume(cache, source, progress)?, Channels::One(0), None),
            };
            progress.stage("finding the window", 0)?;
            progress.set_grid(fascicle_views::VoxelGrid::of(&vol));
            let auto_window = window.unwrap_or_else(|| auto_window(&vol, channel));
            Ok(Content::Slice { volume: vol, channels: channel, auto_window })
        }
        LayerKind::Tractogram { path } => stream_lines(path, progress),
        LayerKind::Axes { length_mm } => Ok(Content::Axes { length_mm: *length_mm }),
    }
}

/// The most points of one part of a tractogram opened as lines (`stream_lines`): compressed to about a
/// quarter on smooth tractography, 1M points are some 5 MB of vertices and indices, one upload of a frame
/// (2M gave `fascicle render` of 1M streamlines 0.3 s and 0.1 GB more: larger transients while parts upload).
pub const LINE_PART_POINTS: usize = 1_000_000;

/// A tractogram file as lines, read and drawn part by part: the file is streamed in parts of whole
/// streamlines (at most [`LINE_PART_POINTS`] points at first, larger later: [`grown_part_points`]), a batch of
/// parts (one per job thread) is read and then built in parallel, and each part is delivered to be drawn while
/// the rest is read ([`stream_parts`]). The whole tractogram is never held (nor the file's bytes): a part's points are let go once its lines are made
/// ([`PreparedTracts::drawn_only`]; a tractogram layer only shows the file, ROIs act on tract layers, which
/// keep theirs).
fn stream_lines(path: &Path, progress: &JobProgress) -> Result<Content, String> {
    let lines = |t: Tractogram, _, _, detail| {
        Content::Tracts(PreparedTracts::lines_in_detail(Arc::new(t), None, detail).drawn_only())
    };
    stream_parts(path, progress, LINE_PART_POINTS, &lines)?
        .ok_or_else(|| format!("{}: the tractogram holds no streamlines", path.display()))
}

/// A tract layer's file (without tensors to sample) read in parts of at most [`PART_POINTS`] points at first
/// (later ones grow: [`grown_part_points`]), never whole ([`stream_parts`]), each made by `prepare` (the part,
/// the layer's index of its first streamline, the lines' detail for the file's size). Each part's streamlines stay addressable (ROIs, picks, saving): a
/// Float32LE `.tck` (what `tckgen` writes) or a TRX with stored float32 positions on a 4-byte boundary (what
/// `fascicle convert` writes) is mapped and each part reads its streamlines in place once its geometry is made
/// ([`PreparedTracts::read_in_place`]: 8 bytes a streamline instead of 12 a point, 1.2 GB for a 1M whole brain);
/// other files keep each part's points. The whole tractogram is not held, nor kept in the
/// cache, so a rebuild reads the file again. An empty file is an empty layer.
fn stream_tract_file(
    path: &Path,
    progress: &JobProgress,
    prepare: &(dyn Fn(TractData, usize, LineDetail) -> Content + Sync),
) -> Result<Content, String> {
    use fascicle_core::io::mapped::{MappedPoints, MappedRun};
    // A file that cannot be read in place (another format, other encodings) keeps its parts' points.
    let mapped = MappedPoints::open_tractogram(path).ok().map(Arc::new);
    let part = |t: Tractogram, first: usize, points_before: usize, detail| {
        let run =
            mapped.as_ref().and_then(|m| MappedRun::consecutive(m.clone(), m.start_after(points_before, first), &t));
        match (prepare(TractData { tractogram: Arc::new(t), tensors: None }, first, detail), run) {
            (Content::Tracts(p), Some(run)) => Content::Tracts(p.read_in_place(Arc::new(run))),
            (content, _) => content,
        }
    };
    Ok(stream_parts(path, progress, PART_POINTS, &part)?
        .unwrap_or_else(|| part(Tractogram::new(), 0, 0, LineDetail::default())))
}

/// The most points of a part in the `batches`-th batch of a file streamed in parts of `first` points at first
/// (`stream_parts`): twice the batch before's, from the third batch on, up to 16 times `first` and at most
/// [`GROWN_PART_POINTS`] (never under `first`). The first parts stay small, so that the first streamlines are
/// drawn soon; the later ones are larger, so that a whole brain does not come as thousands of parts: every
/// frame costs something per part (a draw, and in Bevy's renderer two buffer writes per part and view, each
/// through a staging buffer of its own: at 10M streamlines in 4,160 parts of 250k points, 8,000 writes a
/// frame and a fifth of the viewer's CPU while it orbited).
pub fn grown_part_points(first: usize, batches: usize) -> usize {
    let doublings = batches.saturating_sub(1).min(4) as u32;
    (first << doublings).min(GROWN_PART_POINTS).max(first)
}

/// The most points of a grown part ([`grown_part_points`]): 4M, some 20 MB of vertices and indices as lines
/// compressed to a quarter.
pub const GROWN_PART_POINTS: usize = 4_000_000;

/// Streams a tractogram file in parts of whole streamlines of at most `max_points` points at first (more in
/// later batches: [`grown_part_points`]): a batch of parts (one per job thread) is read, then made by `make`
/// (the part, the file's index of its first streamline, the points of the streamlines before it, the lines'
/// detail for the file's size) in parallel, and delivered through [`JobProgress::parts`] while the next batch
/// is read; a file of one part returns it as it is. `None` for a file without streamlines.
fn stream_parts(
    path: &Path,
    progress: &JobProgress,
    max_points: usize,
    make: &(dyn Fn(Tractogram, usize, usize, LineDetail) -> Content + Sync),
) -> Result<Option<Content>, String> {
    use fascicle_core::io::stream::TractogramReader;
    use rayon::prelude::*;
    let mut reader = TractogramReader::open(path).map_err(|e| e.to_string())?;
    progress.stage("reading the streamlines", reader.header().file_bytes as usize)?;
    // About 12 bytes a point in a .tck or .trk; a TRX header says.
    let header = reader.header();
    let detail = LineDetail::for_points(header.points.map_or(header.file_bytes / 12, |p| p as u64));
    let batch = rayon::current_num_threads().max(1);
    let (mut items, mut points, mut done, mut sent) = (0, 0, 0, 0);
    for batches in 0.. {
        let mut chunks = Vec::with_capacity(batch);
        let part_points = grown_part_points(max_points, batches);
        while chunks.len() < batch
            && let Some(t) = reader.next_chunk(part_points).map_err(|e| e.to_string())?
        {
            let (n, p) = (t.n_streamlines(), t.points.len());
            chunks.push((t, items, points));
            (items, points) = (items + n, points + p);
        }
        progress.advance((reader.bytes_read() as usize).saturating_sub(done));
        done = reader.bytes_read() as usize;
        if progress.is_cancelled() {
            return Err(CANCELLED.into());
        }
        let ended = chunks.len() < batch;
        let mut parts: Vec<Content> =
            chunks.into_par_iter().map(|(t, first, before)| make(t, first, before, detail)).collect();
        if ended && sent == 0 && parts.len() == 1 {
            return Ok(Some(parts.remove(0)));
        }
        sent += parts.len();
        parts.into_iter().for_each(|part| progress.parts.push(part));
        if ended {
            break;
        }
    }
    Ok((items > 0).then_some(Content::Streamed { items }))
}

/// A streamline point's colour: (streamline, the point's index in it, world point) to linear RGB.
pub type ColourFn = dyn Fn(usize, usize, Vec3) -> [f32; 3] + Sync;

/// Values to colour a tractogram (or a part of one) by, aligned with its streamlines.
#[derive(Clone, Copy, Debug)]
pub enum TractValues<'a> {
    /// One per streamline.
    Streamlines(&'a [f32]),
    /// One per point: point `k` of streamline `i` has `values[offsets[i] + k]`.
    Points {
        /// The values, of this tractogram or of a larger one this is a part of.
        values: &'a [f32],
        /// Where each streamline's values start in `values`.
        offsets: &'a [usize],
    },
}

/// The colour of each point of `t`'s streamlines under `colouring` (None: the style's own), as a function of
/// (streamline, point): the direction between a streamline's ends, its length, `scalar` sampled there, or its
/// value in `values` (per streamline or per point of `t`, as the colouring takes them).
pub fn point_colours(
    colouring: &TractColouring,
    t: &Tractogram,
    scalar: Option<&Volume<f32>>,
    values: Option<TractValues>,
) -> Option<Box<ColourFn>> {
    use fascicle_core::dti::splat::viridis;
    let on_viridis = |x: f64| viridis(x).as_vec3().to_array();
    let per_streamline = |f: &dyn Fn(&[Vec3]) -> [f32; 3]| -> Vec<[f32; 3]> { t.iter().map(f).collect() };
    match colouring {
        TractColouring::Style => None,
        TractColouring::Ends => {
            let c = per_streamline(&|s| {
                let d = (s[s.len().saturating_sub(1)] - s[0]).normalize_or_zero().abs();
                d.to_array()
            });
            Some(Box::new(move |i, _, _| c[i]))
        }
        TractColouring::Length { max_mm } => {
            let max = f64::from(max_mm.max(1e-6));
            let c = per_streamline(&|s| {
                on_viridis(s.windows(2).map(|w| f64::from(w[0].distance(w[1]))).sum::<f64>() / max)
            });
            Some(Box::new(move |i, _, _| c[i]))
        }
        TractColouring::Scalar { window: (lo, hi), .. } => {
            let vol = scalar?.clone();
            let inv = vol.world_from_voxel.inverse();
            let (lo, hi) = (f64::from(*lo), f64::from(*hi));
            let span = if hi > lo { hi - lo } else { 1.0 };
            Some(Box::new(move |_, _, p| {
                let v = fascicle_core::dvr::sample(&vol, inv.transform_point3(p.as_dvec3()));
                on_viridis((v - lo) / span)
            }))
        }
        TractColouring::Value { window: (lo, hi), .. } => {
            let Some(TractValues::Streamlines(values)) = values else { return None };
            let (lo, hi) = (f64::from(*lo), f64::from(*hi));
            let span = if hi > lo { hi - lo } else { 1.0 };
            let c: Vec<[f32; 3]> = values.iter().map(|v| on_viridis((f64::from(*v) - lo) / span)).collect();
            Some(Box::new(move |i, _, _| c.get(i).copied().unwrap_or([0.5; 3])))
        }
        TractColouring::PointValue { window: (lo, hi), .. } => {
            let Some(TractValues::Points { values, offsets }) = values else { return None };
            let (lo, hi) = (f64::from(*lo), f64::from(*hi));
            let span = if hi > lo { hi - lo } else { 1.0 };
            // This part's colours, point after point, and where each streamline's start.
            let mut starts = Vec::with_capacity(t.n_streamlines());
            let mut c: Vec<[f32; 3]> = Vec::with_capacity(t.points.len());
            for (i, s) in t.iter().enumerate() {
                starts.push(c.len());
                let from = offsets.get(i).copied().unwrap_or(values.len());
                let v = values.get(from..(from + s.len()).min(values.len())).unwrap_or_default();
                c.extend(v.iter().map(|v| on_viridis((f64::from(*v) - lo) / span)));
                c.resize(starts[i] + s.len(), [0.5; 3]);
            }
            Some(Box::new(move |i, k, _| starts.get(i).and_then(|s| c.get(s + k)).copied().unwrap_or([0.5; 3])))
        }
    }
}

/// One value per point of `t` (point `k` of streamline `i` at `t.offsets[i] + k`): the values of a `.tsf` file
/// (checked as `tsfvalidate` does: as many streamlines, each with as many values as points) or, without one,
/// `t`'s per-point array `name`.
pub fn point_values(t: &Tractogram, file: Option<&Path>, name: &str) -> Result<Vec<f32>, String> {
    if let Some(path) = file {
        let scalars = fascicle_core::io::tsf::read(path).map_err(|e| e.to_string())?;
        scalars.check_against(t, path).map_err(|e| e.to_string())?;
        let mut out = vec![0.0; t.points.len()];
        for i in 0..t.n_streamlines() {
            out[t.offsets[i]..t.offsets[i + 1]].copy_from_slice(scalars.streamline(i));
        }
        return Ok(out);
    }
    match t.scalars.iter().find(|(n, _)| n == name) {
        Some((_, v)) if v.len() == t.points.len() => Ok(v.clone()),
        Some((_, v)) => {
            Err(format!("the per-point array '{name}' has {} values for {} points", v.len(), t.points.len()))
        }
        None => {
            let names: Vec<&str> = t.scalars.iter().map(|(n, _)| n.as_str()).collect();
            Err(format!(
                "no per-point values named '{name}' (the tractogram has {}); give a .tsf file or one of them",
                if names.is_empty() { "none".to_string() } else { names.join(", ") }
            ))
        }
    }
}

/// The value of each streamline of `t`: the weights in `weights` (one per streamline, else an error naming the
/// file), or `t`'s own per-streamline array `name`.
pub fn streamline_values(t: &Tractogram, weights: Option<&Path>, name: &str) -> Result<Vec<f32>, String> {
    if let Some(path) = weights {
        let w = fascicle_core::io::weights::read(path).map_err(|e| e.to_string())?;
        if w.len() != t.n_streamlines() {
            return Err(format!(
                "{}: {} weights, but the tractogram has {} streamlines",
                path.display(),
                w.len(),
                t.n_streamlines()
            ));
        }
        return Ok(w);
    }
    match t.properties.iter().find(|(n, _)| n == name) {
        Some((_, v)) => Ok(v.clone()),
        None => {
            let names: Vec<&str> = t.properties.iter().map(|(n, _)| n.as_str()).collect();
            Err(format!(
                "no per-streamline values named '{name}' (the tractogram has {}); give a weights file or one of them",
                if names.is_empty() { "none".to_string() } else { names.join(", ") }
            ))
        }
    }
}

/// The streamlines of `data` that `keep` marks, with their tensors.
/// A tract layer's include and exclude masks as regions (`tckedit`'s image regions), for
/// [`fascicle_tracts::TractMasks`]: the images read through the cache, a painted mask its voxels (none
/// painted: no region); cutting masks are left out (`cut_by_masks` applies them when the layer is built). An
/// image without a non-zero voxel is an error naming it.
pub fn mask_regions(cache: &DataCache, masks: &[MaskRoi]) -> Result<fascicle_tracts::TractMasks, String> {
    use fascicle_core::roi::RoiMode;
    let mut out = fascicle_tracts::TractMasks::default();
    for m in masks.iter().filter(|m| !m.crop) {
        let Some(region) = mask_region(cache, m, &JobProgress::default())? else { continue };
        let to = if m.mode == RoiMode::Include { &mut out.include } else { &mut out.exclude };
        to.push(region);
    }
    Ok(out)
}

/// A tract layer's mask as a region: its painted voxels (none painted: no region) or its image, read through the
/// cache; an image without a non-zero voxel is an error naming it.
fn mask_region(
    cache: &DataCache,
    m: &MaskRoi,
    progress: &JobProgress,
) -> Result<Option<Arc<fascicle_core::roi::MaskRegion>>, String> {
    use fascicle_core::roi::MaskRegion;
    let region = match &m.painted {
        Some(p) if p.voxels.is_empty() => return Ok(None),
        Some(p) => MaskRegion::new(&p.volume()),
        None => MaskRegion::new(&*image(cache, &m.path, progress)?),
    };
    if region.count() == 0 {
        return Err(format!("{}: the mask image is empty (no non-zero voxel)", m.path.display()));
    }
    Ok(Some(Arc::new(region)))
}

/// `data` cut where its streamlines leave the layer's cutting masks (`tckedit -mask`: each run of two or more
/// points inside one of them becomes a streamline, with its tensors); unchanged without cutting masks.
/// The pieces of a tractogram cut by its layer's cutting masks: the streamline each piece was cut from and the
/// piece's points in it, in order.
type Pieces = Vec<(usize, std::ops::Range<usize>)>;

fn cut_by_masks(
    cache: &DataCache,
    masks: &[MaskRoi],
    data: TractData,
    progress: &JobProgress,
) -> Result<(TractData, Option<Pieces>), String> {
    let mut regions = vec![];
    for m in masks.iter().filter(|m| m.crop) {
        regions.extend(mask_region(cache, m, progress)?.map(fascicle_core::roi::Region::Mask));
    }
    if regions.is_empty() {
        return Ok((data, None));
    }
    progress.stage("cutting the streamlines at the masks", 0)?;
    let t = &data.tractogram;
    let mut out = (Tractogram::new(), vec![]);
    let mut pieces = vec![];
    for s in 0..t.n_streamlines() {
        let first = t.offsets[s];
        for piece in fascicle_core::roi::pieces_inside(t.streamline(s), &regions) {
            out.0.push(&t.points[first + piece.start..first + piece.end]);
            if let Some(tensors) = &data.tensors {
                out.1.extend_from_slice(&tensors[first + piece.start..first + piece.end]);
            }
            pieces.push((s, piece));
        }
    }
    let cut = TractData { tractogram: Arc::new(out.0), tensors: data.tensors.as_ref().map(|_| Arc::new(out.1)) };
    Ok((cut, Some(pieces)))
}

fn subset_of(data: &TractData, keep: &[bool]) -> TractData {
    let mut out = (Tractogram::new(), vec![]);
    for (s, _) in keep.iter().enumerate().filter(|(_, k)| **k) {
        append_streamlines(&mut out, data, s..s + 1);
    }
    TractData { tractogram: Arc::new(out.0), tensors: data.tensors.as_ref().map(|_| Arc::new(out.1)) }
}

/// The files an SH source reads (for cache stamps).
fn source_files(source: &ShSource) -> Vec<&Path> {
    match source {
        ShSource::Nifti { path, .. } => vec![path.as_path()],
        ShSource::PhantomCsa { .. } => vec![],
    }
}

/// The glyph layers one slice away from `kind` along its axis (an SH glyph slice layer; none for others),
/// whose glyphs a background task can place before the user steps there.
pub fn neighbour_slices(kind: &LayerKind, dims: [usize; 3]) -> Vec<LayerKind> {
    let LayerKind::ShGlyphs { axis, index, plane: None, full_volume: false, .. } = kind else { return vec![] };
    let n = dims[axis.index()];
    let k = index.unwrap_or(n / 2);
    [k.checked_sub(1), Some(k + 1).filter(|&j| j < n)]
        .into_iter()
        .flatten()
        .map(|j| {
            let mut other = kind.clone();
            if let LayerKind::ShGlyphs { index, .. } = &mut other {
                *index = Some(j);
            }
            other
        })
        .collect()
}

/// Threads of the jobs' pool ([`set_job_threads`]); 0: one fewer than the cores.
static JOB_THREADS: AtomicUsize = AtomicUsize::new(0);

/// Sizes the jobs' pool, before its first job (later calls change nothing). By default it has one thread fewer
/// than the cores, so that a window's frames keep one; `fascicle render`, whose frames wait for the jobs anyway,
/// gives them every core (1M streamlines read and meshed in about half the time on 2 cores).
pub fn set_job_threads(n: usize) {
    JOB_THREADS.store(n, Ordering::Relaxed);
}

/// The jobs' own rayon threads ([`set_job_threads`]; by default one fewer than the cores, at least one). None
/// when the threads could not be made.
fn job_pool() -> Option<&'static rayon::ThreadPool> {
    static POOL: std::sync::OnceLock<Option<rayon::ThreadPool>> = std::sync::OnceLock::new();
    POOL.get_or_init(|| {
        let cores = std::thread::available_parallelism().map_or(2, |n| n.get());
        let threads = match JOB_THREADS.load(Ordering::Relaxed) {
            0 => cores.saturating_sub(1).max(1),
            n => n,
        };
        rayon::ThreadPoolBuilder::new().num_threads(threads).thread_name(|i| format!("fascicle-job-{i}")).build().ok()
    })
    .as_ref()
}

/// Runs `f` (a layer's job) with its parallel work (fits, tracking, glyph placement) on the jobs' own rayon
/// threads (`job_pool`). The main thread's parallel work (ROI selection as tract parts arrive, as an ROI is
/// dragged) uses the global pool: were the jobs there too, a frame would wait until their queued work was done
/// (a 2.2 s frame while the large bench scene built). Without the pool (threads could not be made), `f` runs on
/// the global one.
pub fn on_job_threads<T: Send>(f: impl FnOnce() -> T + Send) -> T {
    match job_pool() {
        Some(pool) => pool.install(f),
        None => f(),
    }
}

/// A job's result as it is handed from the job's thread to the task that awaits it.
struct JobSlot<T> {
    result: Option<std::thread::Result<T>>,
    waker: Option<std::task::Waker>,
}

/// Starts `f` (a layer's job) on a thread of its own, its parallel work on the jobs' threads
/// ([`on_job_threads`]), and returns a task that is ready with its result; a panic in `f` resumes in the task,
/// as if `f` ran there.
///
/// The job does not run on Bevy's async compute threads, whose task only waits for it: the render world
/// compiles its pipelines there and blocks on one of them (the window's upscaling pipeline), so a long job
/// holding one of those threads froze the window until the job ended (7 s of no frames while 1M streamlines
/// loaded on 2 cores).
pub fn spawn_job<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static) -> bevy::tasks::Task<T> {
    spawn_job_on(f, true)
}

/// [`spawn_job`] for a job with no parallel work (the axes): it runs on its thread alone, never waiting for
/// the jobs' threads. A job on the pool holds one of its threads until it ends, so on 2 cores (one job
/// thread) a small job there waited for a whole-brain read, and its late first frame cost a whole frame more
/// (6 s on lavapipe).
pub fn spawn_light_job<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static) -> bevy::tasks::Task<T> {
    spawn_job_on(f, false)
}

fn spawn_job_on<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static, pooled: bool) -> bevy::tasks::Task<T> {
    let slot = Arc::new(Mutex::new(JobSlot { result: None, waker: None }));
    let done = slot.clone();
    let run = move || {
        let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f));
        let mut s = done.lock().unwrap_or_else(|e| e.into_inner());
        s.result = Some(result);
        if let Some(w) = s.waker.take() {
            w.wake();
        }
    };
    // A thread of its own, so that a small job (the axes) does not queue behind a long one on the pool; its
    // parallel work shares the pool. Should no thread be made, the pool runs it.
    let thread = std::thread::Builder::new().name("fascicle-job".into());
    let run = Arc::new(Mutex::new(Some(run)));
    let take = |run: &Mutex<Option<_>>| run.lock().unwrap_or_else(|e| e.into_inner()).take();
    let on_thread = run.clone();
    let spawned = thread.spawn(move || match take(&on_thread) {
        Some(f) if pooled => on_job_threads(f),
        Some(f) => f(),
        None => {}
    });
    if spawned.is_err()
        && let Some(f) = take(&run)
    {
        match job_pool() {
            Some(pool) => pool.spawn(f),
            None => rayon::spawn(f),
        }
    }
    bevy::tasks::AsyncComputeTaskPool::get().spawn(std::future::poll_fn(move |cx| {
        let mut s = slot.lock().unwrap_or_else(|e| e.into_inner());
        match s.result.take() {
            Some(Ok(value)) => std::task::Poll::Ready(value),
            Some(Err(panic)) => std::panic::resume_unwind(panic),
            None => {
                s.waker = Some(cx.waker().clone());
                std::task::Poll::Pending
            }
        }
    }))
}

/// Places the glyphs of the slices next to an SH glyph layer's into the cache, on a thread of their own (not
/// the layer jobs' pool, so that a job the user is waiting for never queues behind a guess, and not the main
/// thread, should the field have left the cache), counted in `in_flight` while it runs.
pub fn prefetch_neighbours(kind: &LayerKind, cache: &DataCache, in_flight: &Arc<AtomicUsize>) {
    let LayerKind::ShGlyphs { plane: None, full_volume: false, .. } = kind else { return };
    let (kind, cache, in_flight) = (kind.structure(), cache.clone(), in_flight.clone());
    in_flight.fetch_add(1, Ordering::Relaxed);
    let spawned = std::thread::Builder::new().name("fascicle-prefetch".into()).spawn({
        let in_flight = in_flight.clone();
        move || {
            // The layer's job has just read the field: a cache hit.
            if let LayerKind::ShGlyphs { source, .. } = &kind
                && let Ok(field) = sh_field(&cache, source, &JobProgress::default())
            {
                for next in neighbour_slices(&kind, field.coeffs.dims3()) {
                    let _ = on_job_threads(|| build(&next, &cache, &JobProgress::default()));
                }
            }
            in_flight.fetch_sub(1, Ordering::Relaxed);
        }
    });
    if spawned.is_err() {
        in_flight.fetch_sub(1, Ordering::Relaxed);
    }
}

fn tractogram_bytes(t: &Tractogram) -> usize {
    t.points.len() * 12 + t.offsets.len() * 8
}

fn volume_bytes(v: &Volume<f32>) -> usize {
    v.data.len() * 4
}

/// A NIfTI image as f32 (every volume), read once per file state.
pub fn image(cache: &DataCache, path: &Path, progress: &JobProgress) -> Result<Arc<Volume<f32>>, String> {
    progress.stage("reading image", 0)?;
    // NIfTI or MRtrix, by the name.
    cache.get_or_load(&format!("nifti:{path:?}"), &[path], volume_bytes, || {
        fascicle_core::io::mif::read_image::<f32>(path).map_err(|e| e.to_string())
    })
}

/// [`image`], checked to have a 4th-dimension index `volume`.
fn image_with_volume(
    cache: &DataCache,
    path: &Path,
    volume: usize,
    progress: &JobProgress,
) -> Result<Arc<Volume<f32>>, String> {
    let v = image(cache, path, progress)?;
    if volume >= v.n_channels() {
        return Err(format!("volume {volume} requested, the image has {}", v.n_channels()));
    }
    Ok(v)
}

/// The grid of the scenes' built-in ring/cross phantom.
pub const PHANTOM_DIMS: [usize; 3] = [48, 48, 24];

fn phantom(cache: &DataCache) -> Result<Arc<fascicle_core::phantom::Phantom>, String> {
    cache.get_or_load(
        "phantom",
        &[],
        |p: &fascicle_core::phantom::Phantom| p.tensors.len() * 48,
        || Ok(fascicle_core::phantom::ring_cross(PHANTOM_DIMS)),
    )
}

fn phantom_fa(cache: &DataCache) -> Result<Arc<Volume<f32>>, String> {
    let ph = phantom(cache)?;
    cache.get_or_load("phantom-fa", &[], volume_bytes, || Ok(ph.fa()))
}

/// One 3D scalar volume of a source (the chosen 4th-dimension index of a NIfTI).
pub fn scalar_volume(
    cache: &DataCache,
    source: &VolumeSource,
    progress: &JobProgress,
) -> Result<Arc<Volume<f32>>, String> {
    match source {
        VolumeSource::PhantomFa => phantom_fa(cache),
        VolumeSource::Rgb { path } => {
            Err(format!("{}: a colour image shows as a slice; volume rendering needs a scalar image", path.display()))
        }
        VolumeSource::Density { tracts, voxel_mm } => {
            let data = tract_data(cache, tracts, progress)?;
            progress.stage("counting streamlines per voxel", 0)?;
            let key = format!("tdi:{tracts:?}:{voxel_mm}");
            cache.get_or_load(&key, &tract_files(tracts), volume_bytes, || {
                use fascicle_core::tdi::{TdiGrid, track_density};
                let grid = TdiGrid::covering(&data.tractogram, *voxel_mm).map_err(|e| e.to_string())?;
                track_density(&data.tractogram, &grid).map_err(|e| e.to_string())
            })
        }
        VolumeSource::Nifti { path, volume } => {
            let v = image_with_volume(cache, path, *volume, progress)?;
            if v.n_channels() == 1 {
                return Ok(v);
            }
            cache.get_or_load(&format!("nifti:{path:?}:{volume}"), &[path], volume_bytes, || {
                let d = v.dims3();
                let n = d[0] * d[1] * d[2];
                let mut out = Volume::zeros(&d, v.world_from_voxel);
                out.data.copy_from_slice(&v.data[volume * n..(volume + 1) * n]);
                Ok(out)
            })
        }
    }
}

/// The SH field of a source: a coefficient file (its recorded basis first, then the scene's), or CSA ODFs
/// fitted to the phantom's DWI (the whole field, once per order).
pub fn sh_field(cache: &DataCache, source: &ShSource, progress: &JobProgress) -> Result<ShField, String> {
    match source {
        ShSource::PhantomCsa { l_max } => {
            let ph = phantom(cache)?;
            progress.stage("simulating the phantom's DWI", 0)?;
            let dwi = cache.get_or_load(
                "phantom-dwi",
                &[],
                |(v, _): &(Volume<f32>, fascicle_core::io::GradientTable)| volume_bytes(v),
                || ph.dwi(64, 1000.0).map_err(|e| e.to_string()),
            )?;
            let key = format!("sh:{source:?}");
            let field = cache.get_or_load(
                &key,
                &[],
                |f: &ShField| volume_bytes(&f.coeffs),
                || {
                    let (dwi, gtab) = &*dwi;
                    let basis = ShBasis::default();
                    let model = OdfModel::new(gtab, OdfKind::Csa, *l_max, 0.006, basis).map_err(|e| e.to_string())?;
                    progress.stage("fitting CSA ODFs", dwi.n_voxels())?;
                    let coeffs = sh::fit_odf_volume_with_progress(dwi, &model, None, &|n| progress.advance(n))
                        .map_err(|e| e.to_string())?;
                    ShField::new(coeffs, basis)
                },
            )?;
            Ok((*field).clone())
        }
        ShSource::Nifti { path, basis } => {
            progress.stage("reading SH coefficients", 0)?;
            let field = cache.get_or_load(
                &format!("sh:{source:?}"),
                &[path],
                |f: &ShField| volume_bytes(&f.coeffs),
                || {
                    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
                    fascicle_sh_glyphs::layer::read_field(bytes, path, &ShFieldSettings { basis: Some(*basis) })
                },
            )?;
            Ok((*field).clone())
        }
    }
}

/// The tensors of a source, as the tensor plugin's asset.
pub fn tensor_field(cache: &DataCache, source: &TensorSource, progress: &JobProgress) -> Result<TensorField, String> {
    let field = match source {
        TensorSource::Phantom => {
            let p = phantom(cache)?;
            cache.get_or_load(
                "tensor:phantom",
                &[],
                |f: &TensorField| volume_bytes(&f.tensors),
                || {
                    let data = (0..6).flat_map(|c| p.tensors.iter().map(move |t| t[c] as f32)).collect();
                    let shape = vec![p.dims[0], p.dims[1], p.dims[2], 6];
                    TensorField::new(Volume { shape, data, world_from_voxel: p.world_from_voxel })
                },
            )?
        }
        TensorSource::Spiral { .. } => return Err("the spiral is not a voxel grid".into()),
        TensorSource::Nifti { path, order } => {
            progress.stage("reading tensors", 0)?;
            let key = format!("tensor:{path:?}:{order:?}");
            cache.get_or_load(
                &key,
                &[path],
                |f: &TensorField| volume_bytes(&f.tensors),
                || {
                    // The tensor plugin's reader: NIfTI or MRtrix, in the order given, into the voxel frame.
                    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
                    let settings = fascicle_tensors::TensorFieldSettings { order: Some(*order) };
                    fascicle_tensors::layer::read_field(bytes, path, &settings)
                },
            )?
        }
        TensorSource::Dwi { path, bvecs } => {
            use fascicle_core::io::{GradientTable, gradients::DEFAULT_B0_THRESHOLD};
            let dwi = image(cache, path, progress)?;
            let key = format!("tensor:dwi:{path:?}:{}", bvecs.name());
            // The cache stamps the gradient files beside the image too (a .mif carries its own).
            let beside = fascicle_core::io::classify::gradients_beside(path);
            let mut files: Vec<&Path> = vec![path];
            if let Some((bval, bvec)) = &beside {
                files.extend([bval.as_path(), bvec.as_path()]);
            }
            cache.get_or_load(
                &key,
                &files,
                |f: &TensorField| volume_bytes(&f.tensors),
                || {
                    let gtab = GradientTable::of_image(path, dwi.world_from_voxel, *bvecs, DEFAULT_B0_THRESHOLD)
                        .ok_or_else(|| {
                            format!(
                                "{}: no .bval/.bvec beside the image (nor a .mif dw_scheme): it cannot be fitted as a DWI",
                                path.display()
                            )
                        })?
                        .map_err(|e| e.to_string())?;
                    progress.stage("fitting tensors (WLS)", dwi.n_voxels())?;
                    let fit = fascicle_core::dti::fit_volume_with_progress(
                        &*dwi,
                        &gtab,
                        fascicle_core::dti::FitMethod::Wls,
                        None,
                        &|n| progress.advance(n),
                    )
                    .map_err(|e| format!("{}: {e}", path.display()))?;
                    TensorField::new(fit.map_n(6, |t, out| out.copy_from_slice(&t.tensor())))
                },
            )?
        }
    };
    Ok((*field).clone())
}

/// Glyphs on a free plane of interest (any orientation; nearest or trilinear sampling).
pub fn plane_glyphs(
    field: &ShField,
    plane: &GlyphPlane,
    sampling: Sampling,
    style: GlyphStyle,
) -> Result<(Vec<Glyph>, Vec<[u32; 3]>), String> {
    let mut items = sample_plane(&field.coeffs, plane, sampling).map_err(|e| e.to_string())?;
    // Voxel-axis coefficients (DIPY's) into world axes, as the slice glyphs' (`field_glyphs`).
    let affine = field.coeffs.world_from_voxel;
    if let Some(t) = sh::frame::to_world_axes(field.basis, field.l_max(), affine).map_err(|e| e.to_string())? {
        for (_, c, _) in &mut items {
            *c = sh::frame::apply(&t, c);
        }
    }
    let style = style.resolved(plane.spacing);
    let (glyphs, skipped) =
        make_glyphs(items.iter().map(|(p, c, _)| (*p, &c[..])), field.basis, style).map_err(|e| e.to_string())?;
    let voxels = items.iter().enumerate().filter(|(i, _)| !skipped.contains(i)).map(|(_, it)| it.2).collect();
    Ok((glyphs, voxels))
}

/// Tensor glyphs on a slice: one per `spacing`-th voxel with FA >= `min_fa`, tensors rotated into the world
/// frame, largest diameter `size` times the glyph spacing (the plugin's `field_tensor_glyphs`).
#[expect(clippy::too_many_arguments, reason = "a layer kind's fields, passed through")]
pub(crate) fn tensor_glyphs(
    cache: &DataCache,
    source: &TensorSource,
    axis: SliceAxis,
    index: Option<usize>,
    spacing: usize,
    size: f64,
    min_fa: f64,
    progress: &JobProgress,
) -> Result<(Vec<TensorGlyph>, Vec<[u32; 3]>), String> {
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
    let field = tensor_field(cache, source, progress)?;
    progress.set_grid(fascicle_views::VoxelGrid::of(&field.tensors));
    progress.stage("placing glyphs", 0)?;
    let selection = Selection::Slice { axis, index, spacing };
    field_tensor_glyphs(&field, &selection, &TensorGlyphShape { size, min_fa, ..Default::default() })
}

/// Splats of a slab of `thickness` slices centred on a slice: covariance largest standard deviation `size`
/// voxels (colour and opacity unset: apply a `SplatColouring`); the plugin's `field_splats`.
#[expect(clippy::too_many_arguments, reason = "a layer kind's fields, passed through")]
pub(crate) fn slab_splats(
    cache: &DataCache,
    source: &TensorSource,
    axis: SliceAxis,
    index: Option<usize>,
    thickness: usize,
    size: f64,
    min_fa: f64,
    progress: &JobProgress,
) -> Result<Vec<Splat>, String> {
    if let TensorSource::Spiral { n } = source {
        return Ok(fascicle_core::phantom::spiral(*n)
            .into_iter()
            .filter_map(|(c, t)| {
                fascicle_core::dti::splat::tensor_splat(c, &t, size * SPIRAL_EDGE, glam::DVec3::ONE, 1.0)
            })
            .filter(|s| s.fa() >= min_fa)
            .collect());
    }
    let field = tensor_field(cache, source, progress)?;
    progress.set_grid(fascicle_views::VoxelGrid::of(&field.tensors));
    progress.stage("placing splats", 0)?;
    let selection = Selection::Slab { axis, index, thickness };
    field_splats(&field, &selection, &SplatShape { size, min_fa })
}

/// The length sizes of spiral glyphs and splats are fractions of (mm): about the spacing of its tensors.
const SPIRAL_EDGE: f64 = 8.0;

/// A tract source's streamlines, with per-point world tensors when it has them: tracked (the phantom),
/// read (a file, its tensors sampled from a field) or made from peaks, once per source and file state.
pub fn tract_data(cache: &DataCache, source: &TractSource, progress: &JobProgress) -> Result<TractData, String> {
    tract_data_in_parts(cache, source, progress, None)
}

/// A part of the streamlines, delivered while they are tracked.
type OnPart<'a> = &'a (dyn Fn(TractData) + Sync);

/// [`tract_data`], giving the streamlines to `on_part` in parts while they are tracked (only when they are
/// tracked, not when they come from the cache or a file).
pub fn tract_data_in_parts(
    cache: &DataCache,
    source: &TractSource,
    progress: &JobProgress,
    on_part: Option<OnPart>,
) -> Result<TractData, String> {
    let files = tract_files(source);
    let data = cache.get_or_load(
        &format!("tracts:{source:?}"),
        &files,
        |d: &TractData| tract_bytes(d),
        || load_tracts(cache, source, progress, on_part),
    )?;
    Ok((*data).clone())
}

fn tract_bytes(d: &TractData) -> usize {
    tractogram_bytes(&d.tractogram) + d.tensors.as_ref().map_or(0, |t| t.len() * 24)
}

/// `data` in parts of whole streamlines, each of at most `max_points` points (or one streamline, if longer),
/// in order.
pub fn split(data: &TractData, max_points: usize) -> Vec<TractData> {
    let t = &data.tractogram;
    let mut parts = vec![];
    let mut first = 0;
    while first < t.n_streamlines() {
        let start = t.offsets[first];
        let mut last = first + 1;
        while last < t.n_streamlines() && t.offsets[last + 1] - start <= max_points {
            last += 1;
        }
        parts.push(streamlines_of(data, first..last));
        first = last;
    }
    parts
}

/// Streamlines `range` of `data`, with their tensors.
fn streamlines_of(data: &TractData, range: std::ops::Range<usize>) -> TractData {
    let mut out = (Tractogram::new(), vec![]);
    append_streamlines(&mut out, data, range);
    TractData { tractogram: Arc::new(out.0), tensors: data.tensors.as_ref().map(|_| Arc::new(out.1)) }
}

/// Appends streamlines `range` of `d` (and their tensors, when it has them) to `out`.
fn append_streamlines(out: &mut (Tractogram, Vec<[f32; 6]>), d: &TractData, range: std::ops::Range<usize>) {
    append_range(out, &d.tractogram, d.tensors.as_deref().map(|t| t.as_slice()), range);
}

/// Appends streamlines `range` of `t` (and their tensors, when given) to `out`.
fn append_range(
    out: &mut (Tractogram, Vec<[f32; 6]>),
    t: &Tractogram,
    tensors: Option<&[[f32; 6]]>,
    range: std::ops::Range<usize>,
) {
    let (a, b) = (t.offsets[range.start], t.offsets[range.end]);
    let base = out.0.points.len();
    out.0.points.extend_from_slice(&t.points[a..b]);
    out.0.offsets.extend(t.offsets[range.start + 1..=range.end].iter().map(|o| o - a + base));
    if let Some(tensors) = tensors {
        out.1.extend_from_slice(&tensors[a..b]);
    }
}

/// The last streamlines tracked through one field with one set of parameters, per seed: a new seed set
/// re-uses the streamlines of the seeds it shares with it and tracks only the others.
struct SeededTracks {
    /// The seeds (voxel coordinates, as bits), in order.
    seeds: Vec<[u64; 3]>,
    /// Seed `i` gave streamlines `first[i]..first[i + 1]`.
    first: Vec<usize>,
    data: TractData,
}

fn seed_bits(p: glam::DVec3) -> [u64; 3] {
    [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()]
}

/// Seeds tracked per delivered part (a part is also a cancellation point).
fn seeds_per_part(n: usize) -> usize {
    (n / 16).clamp(256, 16_384)
}

/// Tracks `seeds` (voxel coordinates) through `field`: the same streamlines, in seed order, as one
/// [`fascicle_core::tracking::Tracker::run`] over them, but in parts given to `on_part` as they are done (in
/// seed order too, so that a layer numbers them as the result does), and,
/// with `reuse` (a cache key and the field's files), taking the streamlines of seeds that the last tracking
/// under that key also had from it: only new seeds are tracked ([`JobProgress`] counts those).
#[allow(clippy::too_many_arguments, reason = "the tracker's inputs, the cache and the job's channels")]
fn track<F: fascicle_core::tracking::DirectionField + Sync>(
    cache: &DataCache,
    reuse: Option<(&str, &[&Path])>,
    field: &F,
    affine: glam::DMat4,
    params: &fascicle_core::tracking::TrackParams,
    seeds: &[glam::DVec3],
    progress: &JobProgress,
    on_part: Option<OnPart>,
) -> Result<TractData, String> {
    use fascicle_core::tracking::Tracker;
    let last: Option<Arc<SeededTracks>> = reuse.and_then(|(key, files)| cache.peek(key, files));
    let index: std::collections::HashMap<[u64; 3], usize> =
        last.iter().flat_map(|l| l.seeds.iter().enumerate().map(|(i, s)| (*s, i))).collect();
    let old: Vec<Option<usize>> = seeds.iter().map(|s| index.get(&seed_bits(*s)).copied()).collect();
    let missing: Vec<usize> = (0..seeds.len()).filter(|&i| old[i].is_none()).collect();
    let tracker = Tracker::new(field, affine, params.clone()).map_err(|e| e.to_string())?;
    let copy = append_streamlines;
    let finish = |(t, tensors): (Tractogram, Vec<[f32; 6]>)| TractData {
        tractogram: Arc::new(t),
        tensors: Some(Arc::new(tensors)),
    };
    progress.stage("tracking", missing.len())?;
    // The new seeds in blocks, each tracked (in parallel inside) when the walk in seed order below first
    // needs it: (the block's streamlines, the first streamline of each of its seeds).
    let mut blocks = missing.chunks(seeds_per_part(missing.len()));
    let mut block: Option<(TractData, Vec<usize>)> = None;
    // The next of the block's seeds.
    let mut next = 0;
    // In seed order: each seed's streamlines from the last tracking or from its block; the streamlines from
    // `shown` on are given to `on_part` once they fill a part or before a block is tracked, so the layer
    // numbers its streamlines as the result does, reused or not.
    let mut out = (Tractogram::new(), vec![]);
    let mut first = Vec::with_capacity(seeds.len() + 1);
    let mut shown = 0;
    let deliver = |out: &(Tractogram, Vec<[f32; 6]>), shown: &mut usize| {
        let n = out.0.n_streamlines();
        if let Some(on_part) = on_part
            && n > *shown
        {
            let mut part = (Tractogram::new(), vec![]);
            append_range(&mut part, &out.0, Some(&out.1), *shown..n);
            on_part(finish(part));
            *shown = n;
        }
    };
    for o in &old {
        first.push(out.0.n_streamlines());
        match (o, &last) {
            (Some(j), Some(last)) => copy(&mut out, &last.data, last.first[*j]..last.first[*j + 1]),
            _ => {
                if block.as_ref().is_none_or(|(_, f)| next + 1 == f.len()) {
                    if progress.is_cancelled() {
                        return Err(CANCELLED.into());
                    }
                    deliver(&out, &mut shown);
                    let points: Vec<glam::DVec3> = blocks
                        .next()
                        .ok_or("internal error: a seed without its tracking")?
                        .iter()
                        .map(|&i| seeds[i])
                        .collect();
                    let t = tracker.run_with_progress(&points, &|n| progress.advance(n));
                    let mut f = vec![0; points.len() + 1];
                    for &s in &t.seed_index {
                        f[s as usize + 1] += 1;
                    }
                    for k in 0..points.len() {
                        f[k + 1] += f[k];
                    }
                    let data = TractData { tractogram: Arc::new(t.tractogram), tensors: Some(Arc::new(t.tensors)) };
                    (block, next) = (Some((data, f)), 0);
                }
                let (d, f) = block.as_ref().ok_or("internal error: a seed without its tracking")?;
                copy(&mut out, d, f[next]..f[next + 1]);
                next += 1;
            }
        }
        let from = out.0.offsets.get(shown).copied().unwrap_or(0);
        if out.0.points.len() - from >= PART_POINTS {
            deliver(&out, &mut shown);
        }
    }
    deliver(&out, &mut shown);
    first.push(out.0.n_streamlines());
    let data = finish(out);
    if let Some((key, files)) = reuse {
        let seeds = seeds.iter().map(|s| seed_bits(*s)).collect::<Vec<_>>();
        let bytes = tract_bytes(&data) + seeds.len() * 32;
        cache.put(key, files, bytes, Arc::new(SeededTracks { seeds, first, data: data.clone() }));
    }
    Ok(data)
}

/// The files a tract source reads (for cache stamps).
fn tract_files(source: &TractSource) -> Vec<&Path> {
    let mut files: Vec<&Path> = vec![];
    match source {
        TractSource::PhantomRk4 { .. } => {}
        TractSource::File { path, tensors } => {
            files.push(path);
            if let Some(TensorSource::Nifti { path, .. } | TensorSource::Dwi { path, .. }) = tensors {
                files.push(path);
            }
        }
        TractSource::Peaks { path, .. } => files.push(path),
        TractSource::Track { tensors: TensorSource::Nifti { path, .. } | TensorSource::Dwi { path, .. }, .. } => {
            files.push(path)
        }
        TractSource::Track { .. } => {}
    }
    files
}

/// A tensor image (X,Y,Z,6, DIPY order) as the tracker's grid: its dimensions, affine and one f64 tensor per
/// voxel.
fn tensor_grid(f: &Volume<f32>) -> ([usize; 3], glam::DMat4, Vec<[f64; 6]>) {
    let n = f.n_voxels();
    let grid = (0..n).map(|i| std::array::from_fn(|c| f.data[i + n * c] as f64)).collect();
    (f.dims3(), f.world_from_voxel, grid)
}

fn load_tracts(
    cache: &DataCache,
    source: &TractSource,
    progress: &JobProgress,
    on_part: Option<OnPart>,
) -> Result<TractData, String> {
    use fascicle_core::tracking::{TensorInterpolation, TrackParams, tensors_at};
    let field_of = |dims: [usize; 3], affine: glam::DMat4, tensors: Vec<[f64; 6]>| {
        let voxel = glam::DVec3::new(affine.x_axis.length(), affine.y_axis.length(), affine.z_axis.length());
        fascicle_core::tracking::TensorField::new(
            dims,
            voxel,
            tensors.into_iter().map(Some),
            TensorInterpolation::Componentwise,
        )
        .map_err(|e| e.to_string())
    };
    match source {
        TractSource::PhantomRk4 { seed_spacing } => {
            let spacing = (*seed_spacing).max(1);
            let ph = phantom(cache)?;
            let a = ph.world_from_voxel;
            let field = field_of(ph.dims, a, ph.tensors.clone())?;
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
            track(cache, None, &field, a, &params, &seeds, progress, on_part)
        }
        TractSource::File { path, tensors } => {
            progress.stage("reading streamlines", 0)?;
            let t = Tractogram::read(path).map_err(|e| e.to_string())?;
            let Some(source) = tensors else { return Ok(TractData { tractogram: Arc::new(t), tensors: None }) };
            let f = tensor_field(cache, source, progress)?.tensors;
            progress.stage("sampling tensors along the streamlines", 0)?;
            let (dims, affine, grid) = tensor_grid(&f);
            let sampled = tensors_at(&field_of(dims, affine, grid)?, affine, &t.points);
            Ok(TractData { tractogram: Arc::new(t), tensors: Some(Arc::new(sampled)) })
        }
        TractSource::Track { tensors, seeds, params } => {
            let f = tensor_field(cache, tensors, progress)?.tensors;
            let (dims, affine, grid) = tensor_grid(&f);
            let seeds = seed_points(&grid, dims, affine, seeds)?;
            let field = field_of(dims, affine, grid)?;
            // Moving the seeds tracks only the seeds that the last tracking of this field did not have.
            let key = format!("seeded:{tensors:?}:{params:?}");
            let files = tract_files(source);
            track(cache, Some((&key, &files)), &field, affine, params, &seeds, progress, on_part)
        }
        TractSource::Peaks { path, length } => {
            progress.stage("reading peaks", 0)?;
            Ok(TractData { tractogram: Arc::new(peak_segments(path, *length)?), tensors: None })
        }
    }
}

/// Seed points (voxel coordinates) of a tensor grid (DIPY order, X-fastest).
pub fn seed_points(
    tensors: &[[f64; 6]],
    dims: [usize; 3],
    affine: glam::DMat4,
    seeds: &crate::model::Seeds,
) -> Result<Vec<glam::DVec3>, String> {
    use crate::model::Seeds;
    let fa =
        |v: usize| fascicle_core::dti::eigh(&tensors[v]).map_or(0.0, |e| fascicle_core::dti::metrics::fa(&e.values));
    let voxels = (0..dims[2]).flat_map(|z| (0..dims[1]).flat_map(move |y| (0..dims[0]).map(move |x| [x, y, z])));
    let index = |[x, y, z]: [usize; 3]| x + dims[0] * (y + dims[1] * z);
    let out: Vec<glam::DVec3> = match seeds {
        Seeds::Grid { spacing, min_fa } => {
            let s = (*spacing).max(1);
            voxels
                .filter(|p| p.iter().all(|c| c % s == 0) && fa(index(*p)) >= *min_fa)
                .map(|[x, y, z]| glam::DVec3::new(x as f64, y as f64, z as f64))
                .collect()
        }
        Seeds::Sphere { centre, radius, per_voxel } => {
            if !(radius.is_finite() && *radius > 0.0) || *per_voxel == 0 {
                return Err(format!(
                    "a seed sphere needs a positive radius and seeds per voxel (radius {radius}, {per_voxel} per voxel)"
                ));
            }
            let c = glam::Vec3::from(*centre).as_dvec3();
            // A k x k x k sub-grid per voxel, k the smallest with k³ >= per_voxel.
            let k = (1..).find(|k: &usize| k.pow(3) >= *per_voxel).unwrap_or(1);
            let offsets: Vec<glam::DVec3> = (0..k.pow(3))
                .take(*per_voxel)
                .map(|i| {
                    let o = |j: usize| (j as f64 + 0.5) / k as f64 - 0.5;
                    glam::DVec3::new(o(i % k), o((i / k) % k), o(i / (k * k)))
                })
                .collect();
            voxels
                .filter(|&[x, y, z]| {
                    affine.transform_point3(glam::DVec3::new(x as f64, y as f64, z as f64)).distance(c)
                        <= f64::from(*radius)
                })
                .flat_map(|[x, y, z]| offsets.iter().map(move |o| glam::DVec3::new(x as f64, y as f64, z as f64) + *o))
                .collect()
        }
    };
    if out.is_empty() {
        return Err("no seeds: the seed region holds no voxel of the field (or none above the FA cut)".into());
    }
    Ok(out)
}

/// One two-point streamline per peak of a peaks image, through its voxel centre in world coordinates, the
/// voxel's largest peak `length` voxels (of its smallest edge) long and the others in proportion.
pub fn peak_segments(path: &Path, length: f32) -> Result<Tractogram, String> {
    let img = fascicle_core::io::peaks::read(path).map_err(|e| e.to_string())?;
    let a = img.world_from_voxel;
    let m = fascicle_core::io::peaks::direction_frame(a);
    let edge = [a.x_axis, a.y_axis, a.z_axis].iter().map(|c| c.truncate().length()).fold(f64::MAX, f64::min);
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A job does not hold Bevy's async compute threads (where the render world compiles its pipelines and
    /// blocks on one): with one such thread, a task spawned there completes while a job is still running, and
    /// the job's result, or its panic, reaches its task.
    #[test]
    fn jobs_leave_the_async_compute_threads_free() {
        use bevy::tasks::{AsyncComputeTaskPool, TaskPoolBuilder, block_on};
        AsyncComputeTaskPool::get_or_init(|| TaskPoolBuilder::new().num_threads(1).build());
        let (release, wait) = std::sync::mpsc::channel::<()>();
        let job = spawn_job(move || {
            wait.recv().ok();
            42
        });
        let other = AsyncComputeTaskPool::get().spawn(async { 7 });
        assert_eq!(block_on(other), 7, "a task waited for a running job");
        release.send(()).ok();
        assert_eq!(block_on(job), 42);
        let panicking = spawn_job(|| -> u32 { panic!("a job's panic") });
        let joined = std::thread::spawn(move || block_on(panicking)).join();
        assert!(joined.is_err(), "the job's panic resumes in its task");
    }

    /// A light job (the axes) does not wait for the jobs' threads: it completes while jobs hold every one of
    /// them, where a pooled job queues behind them.
    #[test]
    fn a_light_job_does_not_queue_behind_pooled_jobs() {
        use bevy::tasks::{AsyncComputeTaskPool, TaskPoolBuilder, block_on};
        AsyncComputeTaskPool::get_or_init(|| TaskPoolBuilder::new().num_threads(1).build());
        let threads = job_pool().map_or(1, |p| p.current_num_threads());
        let (release, wait) = std::sync::mpsc::channel::<()>();
        let wait = Arc::new(Mutex::new(wait));
        let (started, holding) = std::sync::mpsc::channel::<()>();
        let blockers: Vec<_> = (0..threads)
            .map(|_| {
                let (wait, started) = (wait.clone(), started.clone());
                spawn_job(move || {
                    started.send(()).ok();
                    let _ = wait.lock().map(|w| w.recv());
                })
            })
            .collect();
        for _ in 0..threads {
            holding.recv().unwrap();
        }
        let (queued_tx, queued_rx) = std::sync::mpsc::channel::<()>();
        let queued = spawn_job(move || queued_tx.send(()).ok());
        assert_eq!(block_on(spawn_light_job(|| 5)), 5);
        assert!(
            queued_rx.recv_timeout(std::time::Duration::from_millis(200)).is_err(),
            "a pooled job ran while every job thread was held: the test shows nothing"
        );
        for _ in 0..threads {
            release.send(()).ok();
        }
        for b in blockers {
            block_on(b);
        }
        block_on(queued);
    }

    /// Tracts from a file with a tensor field: the phantom's RK4 tracts written to `.tck` and read back with
    /// the phantom's tensors carry the tensors the tracker recorded (to f32 rounding of the points);
    /// without, none; a field that is not a voxel grid is a clear error.
    #[test]
    fn file_tracts_take_tensors_from_a_field() {
        let (cache, p) = (DataCache::default(), JobProgress::default());
        let tracked = tract_data(&cache, &TractSource::PhantomRk4 { seed_spacing: 6 }, &p).unwrap();
        let (t, tracked) = (tracked.tractogram, tracked.tensors.unwrap());
        let tmp_path = tempfile::tempdir().unwrap();
        let path = tmp_path.path().join("fascicle-file-tensors.tck");
        fascicle_core::io::tck::write(&path, &t, &[]).unwrap();
        let file = |tensors| TractSource::File { path: path.clone(), tensors };
        let back = tract_data(&cache, &file(Some(TensorSource::Phantom)), &p).unwrap();
        let sampled = back.tensors.unwrap();
        assert_eq!(back.tractogram.points.len(), tracked.len());
        let scale = tracked.iter().flatten().fold(0f32, |m, v| m.max(v.abs()));
        let worst = sampled
            .iter()
            .zip(tracked.iter())
            .flat_map(|(a, b)| a.iter().zip(b).map(|(x, y)| (x - y).abs()))
            .fold(0f32, f32::max);
        assert!(worst <= 1e-4 * scale, "{worst} vs {scale}");
        assert!(tract_data(&cache, &file(None), &p).unwrap().tensors.is_none());
        let err = tract_data(&cache, &file(Some(TensorSource::Spiral { n: 10 })), &p).err().unwrap();
        assert!(err.contains("not a voxel grid"), "{err}");
        std::fs::remove_file(path).ok();
    }

    fn data(path: &str) -> std::path::PathBuf {
        crate::repo_path("data").join(path)
    }

    /// Tracking on a user's data: from a DWI (tensors fitted in the job, WLS) and from the tensor file that
    /// `fascicle fit dti` wrote for the same DWI, the streamlines agree (the file holds float32 tensors);
    /// the fit is cached (a second layer on the same DWI fits nothing); progress counts every seed.
    #[test]
    fn tracking_runs_on_a_dwi_and_on_its_tensor_file() {
        use crate::model::Seeds;
        use fascicle_core::tracking::{Integrator, TrackParams};
        let cache = DataCache::default();
        let params = TrackParams { step_mm: 0.5, integrator: Integrator::Euler, ..TrackParams::default() };
        let seeds = Seeds::Grid { spacing: 1, min_fa: 0.3 };
        let track = |tensors: TensorSource, p: &JobProgress| {
            tract_data(&cache, &TractSource::Track { tensors, seeds: seeds.clone(), params: params.clone() }, p)
        };
        let p = JobProgress::default();
        let from_dwi =
            track(TensorSource::Dwi { path: data("dwi/small_64D.nii"), bvecs: Default::default() }, &p).unwrap();
        let (stage, done) = p.snapshot();
        assert_eq!((stage, done), ("tracking", Some(1.0)));
        let file = TensorSource::Nifti { path: data("dti/small_64D_tensor.nii.gz"), order: Default::default() };
        let from_file = track(file, &JobProgress::default()).unwrap();
        let (a, b) = (&from_dwi.tractogram, &from_file.tractogram);
        assert!(a.n_streamlines() > 50, "{} streamlines", a.n_streamlines());
        assert_eq!(a.n_streamlines(), b.n_streamlines());
        let worst = a.points.iter().zip(&b.points).map(|(x, y)| x.distance(*y)).fold(0f32, f32::max);
        assert!(
            a.points.len() == b.points.len() && worst < 1e-3,
            "{} vs {} points, {worst} mm",
            a.points.len(),
            b.points.len()
        );
        assert_eq!(from_dwi.tensors.as_ref().map(|t| t.len()), Some(a.points.len()));
        let loads = cache.stats().loads;
        let glyphs = tensor_glyphs(
            &cache,
            &TensorSource::Dwi { path: data("dwi/small_64D.nii"), bvecs: Default::default() },
            SliceAxis::Z,
            None,
            1,
            0.9,
            0.0,
            &p,
        );
        assert!(glyphs.unwrap().0.len() > 10);
        assert_eq!(cache.stats().loads, loads, "the fit is reused");
        // A DWI without gradient files beside it is a clear error.
        let e = tensor_field(
            &cache,
            &TensorSource::Dwi { path: data("dti/small_64D_fa.nii.gz"), bvecs: Default::default() },
            &p,
        )
        .err()
        .unwrap();
        assert!(e.contains("no .bval/.bvec beside"), "{e}");
    }

    /// A density layer of a tractogram: every streamline counts in at least one voxel and at most once per
    /// voxel, on the asked voxel size; the slice shows it; a missing tractogram is the tract source's error.
    #[test]
    fn density_maps_of_tract_sources() {
        let cache = DataCache::default();
        let p = JobProgress::default();
        let tracts = TractSource::File { path: data("tracts/tracks300.trk"), tensors: None };
        let n = tract_data(&cache, &tracts, &p).unwrap().tractogram.n_streamlines() as f32;
        let source = VolumeSource::Density { tracts: tracts.clone(), voxel_mm: 2.0 };
        let tdi = scalar_volume(&cache, &source, &p).unwrap();
        assert!((tdi.voxel_size() - glam::DVec3::splat(2.0)).length() < 1e-12);
        let max = tdi.data.iter().copied().fold(0.0, f32::max);
        assert!(max > 1.0 && max <= n && tdi.data.iter().sum::<f32>() >= n, "max {max} of {n} streamlines");
        let slice = LayerKind::Slice { source, axis: SliceAxis::Z, index: None, window: None };
        assert!(matches!(build(&slice, &cache, &p), Ok(Content::Slice { .. })));
        let missing = VolumeSource::Density {
            tracts: TractSource::File { path: data("tracts/none.trk"), tensors: None },
            voxel_mm: 1.0,
        };
        assert!(scalar_volume(&cache, &missing, &p).err().unwrap().contains("none.trk"));
    }

    /// Sphere seeds: `per_voxel` seeds in each voxel whose centre is inside the sphere, spread within it.
    #[test]
    fn sphere_seeds_fill_the_voxels_inside() {
        use crate::model::Seeds;
        let dims = [10, 10, 10];
        let grid = vec![[1.0, 0.0, 1.0, 0.0, 0.0, 1.0]; 1000];
        let affine = glam::DMat4::from_scale(glam::DVec3::splat(2.0));
        let seeds = Seeds::Sphere { centre: [10.0, 10.0, 10.0], radius: 3.0, per_voxel: 8 };
        let pts = seed_points(&grid, dims, affine, &seeds).unwrap();
        // Voxel centres within 3 mm of (10,10,10) mm = voxel (5,5,5), 2 mm voxels: the centre, its 6 face
        // neighbours (2 mm) and 12 edge neighbours (2.83 mm); corners (3.46 mm) are out.
        assert_eq!(pts.len(), 19 * 8);
        assert!(pts.iter().all(|p| (*p - glam::DVec3::splat(5.0)).abs().max_element() <= 1.25));
        let none = Seeds::Sphere { centre: [500.0, 0.0, 0.0], radius: 1.0, per_voxel: 1 };
        assert!(seed_points(&grid, dims, affine, &none).unwrap_err().contains("no seeds"));
    }

    /// Moving a seed sphere tracks only the seeds that are new: the job's tracking stage counts exactly the
    /// seeds of the new sphere that the old one did not have, and the streamlines (points, offsets, tensors)
    /// are bit for bit those of tracking the new sphere from nothing. Other parameters do not reuse.
    #[test]
    fn moving_seeds_tracks_only_the_new_ones() {
        use crate::model::Seeds;
        use fascicle_core::tracking::TrackParams;
        let source = |centre: [f32; 3], params: TrackParams| TractSource::Track {
            tensors: TensorSource::Phantom,
            seeds: Seeds::Sphere { centre, radius: 6.0, per_voxel: 8 },
            params,
        };
        let (a, b) = ([28.0, 0.0, 0.0], [28.0, 2.0, 0.0]);
        let cache = DataCache::default();
        let first = tract_data(&cache, &source(a, TrackParams::default()), &JobProgress::default()).unwrap();
        assert!(first.tractogram.n_streamlines() > 100, "{} streamlines", first.tractogram.n_streamlines());
        let moved = JobProgress::default();
        let delivered = Mutex::new(vec![]);
        let on_part = |part: TractData| delivered.lock().unwrap().push(part);
        let reused = tract_data_in_parts(&cache, &source(b, TrackParams::default()), &moved, Some(&on_part)).unwrap();

        // The seeds of each sphere, as the job computes them.
        let f = tensor_field(&cache, &TensorSource::Phantom, &JobProgress::default()).unwrap().tensors;
        let (dims, affine, grid) = tensor_grid(&f);
        let seeds = |c| {
            let s = Seeds::Sphere { centre: c, radius: 6.0, per_voxel: 8 };
            seed_points(&grid, dims, affine, &s).unwrap().into_iter().map(seed_bits).collect::<Vec<_>>()
        };
        let (old, new) = (seeds(a), seeds(b));
        let fresh: usize = new.iter().filter(|s| !old.contains(s)).count();
        assert!(fresh > 0 && fresh < new.len() / 2, "{fresh} of {} seeds are new", new.len());
        let first_new = new.iter().position(|s| !old.contains(s)).unwrap();
        assert!(new[first_new..].iter().any(|s| old.contains(s)), "new and reused seeds interleave");
        assert_eq!(moved.total.load(Ordering::Relaxed), fresh, "only the new seeds are tracked");

        let scratch = tract_data(&DataCache::default(), &source(b, TrackParams::default()), &JobProgress::default());
        let scratch = scratch.unwrap();
        assert_eq!(reused.tractogram.offsets, scratch.tractogram.offsets);
        assert_eq!(reused.tractogram.points, scratch.tractogram.points);
        assert_eq!(reused.tensors, scratch.tensors);
        // The parts come in seed order, reused streamlines among the new ones: a layer numbers its
        // streamlines as a fresh tracking does (the indices of deleted streamlines point at the same ones).
        let mut joined = Tractogram::new();
        let mut tensors = vec![];
        for p in delivered.into_inner().unwrap() {
            p.tractogram.iter().for_each(|s| joined.push(s));
            tensors.extend_from_slice(p.tensors.as_deref().unwrap());
        }
        assert_eq!(joined.offsets, scratch.tractogram.offsets);
        assert_eq!(joined.points, scratch.tractogram.points);
        assert_eq!(Some(&tensors), scratch.tensors.as_deref());

        // Another step length: nothing of the last tracking applies.
        let other = JobProgress::default();
        let params = TrackParams { step_mm: 0.25, ..TrackParams::default() };
        tract_data(&cache, &source(b, params), &other).unwrap();
        assert_eq!(other.total.load(Ordering::Relaxed), new.len());
    }

    /// Tracking delivers its streamlines in parts while it runs: the first part comes before the last seed is
    /// tracked, and the parts in order are the whole result.
    #[test]
    fn tracking_delivers_parts_as_it_goes() {
        let (cache, progress) = (DataCache::default(), JobProgress::default());
        let delivered = Mutex::new(vec![]);
        let on_part = |part: TractData| {
            let done = progress.done.load(Ordering::Relaxed);
            delivered.lock().unwrap().push((done, part));
        };
        let all = tract_data_in_parts(&cache, &TractSource::PhantomRk4 { seed_spacing: 1 }, &progress, Some(&on_part))
            .unwrap();
        let parts = delivered.into_inner().unwrap();
        let total = progress.total.load(Ordering::Relaxed);
        assert!(parts.len() >= 2 && total > 512, "{} parts of {total} seeds", parts.len());
        assert!(parts[0].0 < total, "the first part came after {} of {total} seeds", parts[0].0);
        let mut joined = Tractogram::new();
        let mut tensors = vec![];
        for (_, p) in &parts {
            p.tractogram.iter().for_each(|s| joined.push(s));
            tensors.extend_from_slice(p.tensors.as_deref().unwrap());
        }
        assert_eq!(joined.offsets, all.tractogram.offsets);
        assert_eq!(joined.points, all.tractogram.points);
        assert_eq!(Some(&tensors), all.tensors.as_deref());
    }

    /// A large tractogram goes to the layer in parts of whole streamlines of at most the limit (one
    /// streamline longer than the limit is a part of its own), in order and complete; the parts of a tract
    /// layer from a file are built by the job and the content says so, each knowing its first streamline.
    #[test]
    fn large_tractograms_are_split_into_parts() {
        let mut t = Tractogram::new();
        for k in 0..50usize {
            let n = [1, 7, 30, 3][k % 4];
            t.push(&(0..n).map(|i| Vec3::new(k as f32, i as f32, 0.0)).collect::<Vec<_>>());
        }
        let tensors: Vec<[f32; 6]> = (0..t.points.len()).map(|i| [i as f32; 6]).collect();
        let data = TractData { tractogram: Arc::new(t.clone()), tensors: Some(Arc::new(tensors.clone())) };
        let parts = split(&data, 20);
        let mut joined = Tractogram::new();
        let mut joined_tensors = vec![];
        for p in &parts {
            let n = p.tractogram.points.len();
            assert!(n <= 20 || p.tractogram.n_streamlines() == 1, "a part of {n} points");
            p.tractogram.iter().for_each(|s| joined.push(s));
            joined_tensors.extend_from_slice(p.tensors.as_deref().unwrap());
        }
        assert_eq!((joined.offsets, joined.points), (t.offsets.clone(), t.points.clone()));
        assert_eq!(joined_tensors, tensors);
        assert!(split(&TractData { tractogram: Arc::new(Tractogram::new()), tensors: None }, 20).is_empty());

        // Through a layer: a file of more than PART_POINTS points arrives in parts, read part by part.
        let mut big = Tractogram::new();
        for k in 0..(PART_POINTS / 100 + 10) {
            big.push(&(0..100).map(|i| Vec3::new(k as f32 * 0.01, i as f32 * 0.5, 0.0)).collect::<Vec<_>>());
        }
        let tmp_path = tempfile::tempdir().unwrap();
        let path = tmp_path.path().join("fascicle-parts.tck");
        fascicle_core::io::tck::write(&path, &big, &[]).unwrap();
        let kind = LayerKind::Tracts {
            source: TractSource::File { path: path.clone(), tensors: None },
            mode: TractMode::Lines,
            render: Default::default(),
            rois: vec![],
            masks: vec![],
            ends_only: false,
            deleted: vec![],
            colouring: Default::default(),
        };
        let (cache, progress) = (DataCache::default(), JobProgress::default());
        let content = build(&kind, &cache, &progress).unwrap();
        assert!(matches!(content, Content::Streamed { items } if items == big.n_streamlines()));
        // Read in parts, never whole: the cache holds no copy of the file's streamlines.
        assert!(cache.is_empty(), "the cache holds {} values", cache.len());
        let mut streamlines = 0;
        while let Some(part) = progress.parts.pop() {
            let Content::Tracts(p) = part else { panic!("a part that is not tracts") };
            let t = p.tractogram.expect("a tract layer's part keeps its streamlines");
            // A Float32LE .tck: read in place, not kept in memory.
            assert!(matches!(t, fascicle_tracts::SetStreamlines::Mapped(_)), "a part of a .tck kept its points");
            assert!((0..t.n_streamlines()).map(|s| t.streamline(s).len()).sum::<usize>() <= PART_POINTS);
            // Each part knows where it starts among the layer's streamlines (picks and deletions index those),
            // and reads the file's streamlines from there.
            assert_eq!(p.first, streamlines);
            for s in 0..t.n_streamlines() {
                assert_eq!(t.streamline(s), big.streamline(p.first + s), "streamline {}", p.first + s);
            }
            streamlines += t.n_streamlines();
        }
        assert_eq!(streamlines, big.n_streamlines());
        std::fs::remove_file(path).ok();
    }

    /// Parts grow from the third batch on, doubling to 16 times the first parts' size, never over
    /// [`GROWN_PART_POINTS`] unless the first parts are larger: a 10M-streamline tract layer (1.04G points)
    /// comes in some 270 parts instead of 4,160.
    #[test]
    fn parts_grow_after_the_first_batches() {
        let sizes: Vec<usize> = (0..8).map(|b| grown_part_points(PART_POINTS, b)).collect();
        let k = 250_000;
        assert_eq!(sizes, [k, k, 2 * k, 4 * k, 8 * k, 16 * k, 16 * k, 16 * k]);
        assert_eq!(grown_part_points(LINE_PART_POINTS, 9), GROWN_PART_POINTS);
        assert_eq!(grown_part_points(GROWN_PART_POINTS * 2, 9), GROWN_PART_POINTS * 2);
        // Two job threads, as here: the parts of a 10M whole brain.
        let (mut left, mut parts) = (1_040_000_000usize, 0);
        for b in 0.. {
            for _ in 0..2 {
                left = left.saturating_sub(grown_part_points(PART_POINTS, b));
                parts += 1;
            }
            if left == 0 {
                break;
            }
        }
        assert!((250..300).contains(&parts), "{parts} parts");
    }

    /// A tractogram layer streams its file in parts of at most [`LINE_PART_POINTS`] points, each part drawn only
    /// (its points let go once its lines are made): every streamline arrives once, in order of the parts' counts,
    /// and each part's lines hold exactly the segments of its streamlines compressed to the line tolerance.
    #[test]
    fn tractogram_layers_stream_their_file_and_keep_no_points() {
        use fascicle_core::compress::{Compression, compress};
        use fascicle_tracts::{LINE_TOLERANCE_MM, PreparedGeometry, line_segments};
        let segments = |t: &Tractogram| {
            let c = compress(t, Compression { tolerance_mm: LINE_TOLERANCE_MM, ..Compression::default() });
            c.iter().map(|s| s.len() - 1).sum::<usize>()
        };
        let check = |content: Content| -> (usize, usize) {
            let Content::Tracts(p) = content else { panic!("a part that is not tracts") };
            assert!(p.tractogram.is_none(), "a tractogram layer's part kept its points");
            let PreparedGeometry::Mesh { mesh, preview, .. } = p.geometry else { panic!("not lines") };
            assert!(preview.is_some(), "lines without a preview");
            (p.n_streamlines, line_segments(&mesh))
        };
        // One part: DIPY's 300 streamlines.
        let path = data("tracts/tracks300.trk");
        let t = Tractogram::read(&path).unwrap();
        let one = build(&LayerKind::Tractogram { path }, &DataCache::default(), &JobProgress::default()).unwrap();
        assert_eq!(check(one), (t.n_streamlines(), segments(&t)));

        // Several parts: 2.4M points on wavy lines.
        let mut big = Tractogram::new();
        for k in 0..24_000 {
            let s: Vec<Vec3> = (0..100)
                .map(|i| Vec3::new(k as f32 * 0.01, i as f32 * 0.5, (i as f32 * 0.3 + k as f32).sin()))
                .collect();
            big.push(&s);
        }
        let tmp_path = tempfile::tempdir().unwrap();
        let path = tmp_path.path().join("fascicle-stream-lines.tck");
        fascicle_core::io::tck::write(&path, &big, &[]).unwrap();
        let progress = JobProgress::default();
        let content = build(&LayerKind::Tractogram { path: path.clone() }, &DataCache::default(), &progress);
        std::fs::remove_file(&path).ok();
        assert!(matches!(content, Ok(Content::Streamed { items }) if items == big.n_streamlines()));
        let (mut streamlines, mut lines, mut parts) = (0, 0, 0);
        while let Some(part) = progress.parts.pop() {
            let (n, l) = check(part);
            (streamlines, lines, parts) = (streamlines + n, lines + l, parts + 1);
        }
        assert!(parts >= 2, "{parts} parts");
        assert_eq!((streamlines, lines), (big.n_streamlines(), segments(&big)));
    }

    /// Tract colourings, checked on the line mesh a layer's job builds: every vertex of a streamline takes the
    /// direction between its ends, or viridis of its length, or viridis of a linear scalar image (trilinear
    /// sampling is exact on it) at the vertex; hyperstreamlines take the same colours at their tubelets' ends.
    #[test]
    fn tracts_are_coloured_by_ends_length_and_a_scalar_image() {
        use crate::model::TractColouring;
        use bevy::mesh::{Mesh, VertexAttributeValues};
        use fascicle_core::dti::splat::viridis;
        let path = data("tracts/tracks300.trk");
        let t = Tractogram::read(&path).unwrap();
        // A ramp along x: value = (x mm) / 100, on a 2 mm grid covering the streamlines.
        let tmp_ramp = tempfile::tempdir().unwrap();
        let ramp = tmp_ramp.path().join("fascicle-ramp.nii.gz");
        let affine = glam::DMat4::from_scale_rotation_translation(
            glam::DVec3::splat(2.0),
            glam::DQuat::IDENTITY,
            glam::DVec3::new(40.0, 60.0, 40.0),
        );
        let mut vol = Volume::<f32>::zeros(&[50, 50, 40], affine);
        for (i, v) in vol.data.iter_mut().enumerate() {
            *v = (40.0 + 2.0 * (i % 50) as f32) / 100.0;
        }
        fascicle_core::io::nifti::write(&ramp, &vol, fascicle_core::io::nifti::WriteType::F32).unwrap();
        // (position, colour, streamline in the drawn set) of each vertex of the layer's line mesh.
        type Vertices = (Vec<[f32; 3]>, Vec<[f32; 4]>, Vec<usize>);
        let colours = |colouring: TractColouring| -> Vertices {
            let kind = LayerKind::Tracts {
                source: TractSource::File { path: path.clone(), tensors: None },
                mode: TractMode::Lines,
                render: Default::default(),
                rois: vec![],
                masks: vec![],
                ends_only: false,
                deleted: vec![],
                colouring,
            };
            let Ok(Content::Tracts(p)) = build(&kind, &DataCache::default(), &JobProgress::default()) else {
                panic!("no tracts")
            };
            let fascicle_tracts::PreparedGeometry::Mesh { mesh, .. } = p.geometry else { panic!("not a mesh") };
            let pos = match mesh.attribute(Mesh::ATTRIBUTE_POSITION) {
                Some(VertexAttributeValues::Float32x3(v)) => v.clone(),
                _ => panic!("positions"),
            };
            let col = match mesh.attribute(fascicle_tracts::ATTRIBUTE_RGBA8) {
                Some(VertexAttributeValues::Unorm8x4(v)) => v.iter().map(|c| c.map(|x| f32::from(x) / 255.0)).collect(),
                _ => panic!("colours"),
            };
            let owners = match mesh.attribute(fascicle_tracts::ATTRIBUTE_STREAMLINE) {
                Some(VertexAttributeValues::Uint32(v)) => v.iter().map(|s| *s as usize).collect(),
                _ => panic!("streamlines"),
            };
            (pos, col, owners)
        };
        // Colours are 8-bit: within half a step of the colour function.
        let close = |a: [f32; 4], b: glam::Vec3| {
            (glam::Vec3::new(a[0], a[1], a[2]) - b).abs().max_element() < 0.5 / 255.0 + 1e-5
        };

        let (_, ends, owners) = colours(TractColouring::Ends);
        // Every streamline of two points or more is drawn (one-point streamlines draw no line).
        let drawn: std::collections::BTreeSet<usize> = owners.iter().copied().collect();
        assert_eq!(drawn.len(), t.iter().filter(|s| s.len() >= 2).count());
        for (c, &s) in ends.iter().zip(&owners) {
            let p = t.streamline(s);
            assert!(close(*c, (p[p.len() - 1] - p[0]).normalize().abs()), "streamline {s}: {c:?}");
        }
        let (_, by_length, owners) = colours(TractColouring::Length { max_mm: 120.0 });
        for (c, &s) in by_length.iter().zip(&owners) {
            let len: f64 = t.streamline(s).windows(2).map(|w| f64::from(w[0].distance(w[1]))).sum();
            assert!(close(*c, viridis(len / 120.0).as_vec3()), "streamline {s}: {c:?}");
        }
        let source = VolumeSource::Nifti { path: ramp.clone(), volume: 0 };
        let (pos, by_x, _) = colours(TractColouring::Scalar { source: source.clone(), window: (0.6, 1.2) });
        for (c, p) in by_x.iter().zip(&pos) {
            assert!(close(*c, viridis((f64::from(p[0]) / 100.0 - 0.6) / 0.6).as_vec3()), "at {p:?}: {c:?}");
        }
        // A value per streamline from a weights file (tcksift2's text): streamline s weighs s / 300; with a
        // minimum of 0.5 only the upper half is drawn, each in viridis of its weight.
        let tmp_weights = tempfile::tempdir().unwrap();
        let weights = tmp_weights.path().join("fascicle-weights.txt");
        let w: Vec<f32> = (0..t.n_streamlines()).map(|s| s as f32 / 300.0).collect();
        fascicle_core::io::weights::write(&weights, &w).unwrap();
        let value = |min| TractColouring::Value {
            weights: Some(weights.clone()),
            name: String::new(),
            window: (0.0, 1.0),
            min,
        };
        let (_, by_weight, owners) = colours(value(None));
        for (c, &s) in by_weight.iter().zip(&owners) {
            assert!(close(*c, viridis(f64::from(w[s])).as_vec3()), "streamline {s}: {c:?}");
        }
        let (_, upper, upper_owners) = colours(value(Some(0.5)));
        let kept: Vec<usize> = (0..t.n_streamlines()).filter(|&s| w[s] >= 0.5).collect();
        let drawn: std::collections::BTreeSet<usize> = upper_owners.iter().map(|k| kept[*k]).collect();
        let expected: std::collections::BTreeSet<usize> =
            kept.iter().copied().filter(|&s| t.streamline(s).len() >= 2).collect();
        assert_eq!(drawn, expected, "only the streamlines weighing 0.5 or more");
        for (c, &k) in upper.iter().zip(&upper_owners) {
            let s = kept[k];
            assert!(close(*c, viridis(f64::from(w[s])).as_vec3()), "streamline {s}: {c:?}");
        }
        // A weights file of the wrong length, or a value name the file lacks: errors naming them.
        fascicle_core::io::weights::write(&weights, &w[..10]).unwrap();
        let kind = |colouring| LayerKind::Tracts {
            source: TractSource::File { path: path.clone(), tensors: None },
            mode: TractMode::Lines,
            render: Default::default(),
            rois: vec![],
            masks: vec![],
            ends_only: false,
            deleted: vec![],
            colouring,
        };
        let e = build(&kind(value(None)), &DataCache::default(), &JobProgress::default()).err().unwrap();
        assert!(e.contains("10 weights, but the tractogram has 300"), "{e}");
        let named = TractColouring::Value { weights: None, name: "sift".into(), window: (0.0, 1.0), min: None };
        let e = build(&kind(named), &DataCache::default(), &JobProgress::default()).err().unwrap();
        assert!(e.contains("no per-streamline values named 'sift'"), "{e}");
        std::fs::remove_file(&weights).ok();
        // A value per point from a track scalar file (`.tsf`, as tcksample writes it): point k of each
        // streamline has the value k, so each vertex has the colour of its own point's index.
        let tmp_tsf = tempfile::tempdir().unwrap();
        let tsf = tmp_tsf.path().join("fascicle-points.tsf");
        let by_index = fascicle_core::io::tsf::TrackScalars::for_tractogram(&t, |_, k| k as f32);
        fascicle_core::io::tsf::write(&tsf, &by_index).unwrap();
        let per_point = |file: Option<std::path::PathBuf>, name: &str| TractColouring::PointValue {
            file,
            name: name.into(),
            window: (0.0, 100.0),
        };
        let (pos, by_point, owners) = colours(per_point(Some(tsf.clone()), ""));
        assert!(pos.len() > 1000);
        for ((c, p), &s) in by_point.iter().zip(&pos).zip(&owners) {
            let k =
                t.streamline(s).iter().position(|q| q.to_array() == *p).expect("a vertex is a point of its streamline");
            assert!(close(*c, viridis(k as f64 / 100.0).as_vec3()), "streamline {s} point {k}: {c:?}");
        }
        // The tractogram's own per-point array by name (a .trk's scalars, a TRX's dpp) colours the same.
        let mut named_t = t.clone();
        named_t.scalars = vec![("index".into(), by_index.values.clone())];
        assert_eq!(point_values(&named_t, None, "index").unwrap(), point_values(&t, Some(&tsf), "").unwrap());
        let e = point_values(&named_t, None, "fa").err().unwrap();
        assert!(e.contains("no per-point values named 'fa' (the tractogram has index)"), "{e}");
        // A .tsf of another tractogram: an error naming the file.
        let mut other = t.clone();
        other.offsets.pop();
        other.points.truncate(*other.offsets.last().unwrap());
        fascicle_core::io::tsf::write(&tsf, &fascicle_core::io::tsf::TrackScalars::for_tractogram(&other, |_, _| 1.0))
            .unwrap();
        let e = point_values(&t, Some(&tsf), "").err().unwrap();
        assert!(e.contains(&tsf.display().to_string()), "{e}");
        std::fs::remove_file(&tsf).ok();
        // Hyperstreamlines: the tubelets' end colours (packed after the geometry) are the same function.
        let colouring = TractColouring::Scalar { source, window: (0.6, 1.2) };
        let c = point_colours(&colouring, &t, Some(&vol), None).unwrap();
        let tubes =
            fascicle_tracts::PreparedTracts::tubes_coloured(Arc::new(t.clone()), None, &Default::default(), Some(&*c));
        assert!(
            matches!(tubes.geometry, fascicle_tracts::PreparedGeometry::Tubes { n_tubelets, .. } if n_tubelets > 1000)
        );
        std::fs::remove_file(ramp).ok();
    }

    /// Mask images as a tract layer's regions keep what tckedit's image regions keep (the core's `Criteria`,
    /// itself tested against `tckedit`): an include mask the streamlines through a slab of voxels, an exclude
    /// mask the others, with ends only those with an end in it; with a value threshold, both apply. An empty
    /// mask is an error naming the file. Include and exclude masks select among the streamlines built (the
    /// build keeps them all), cutting masks cut them in the build.
    #[test]
    fn mask_regions_keep_what_tckedit_keeps() {
        use crate::model::{MaskRoi, TractColouring};
        use fascicle_core::roi::{Criteria, MaskRegion, Region, RoiMode};
        let path = data("tracts/tracks300.trk");
        let t = Tractogram::read(&path).unwrap();
        // A 1 mm grid over the streamlines, set on the slab 88 <= x < 94 mm.
        let affine = glam::DMat4::from_translation(glam::DVec3::new(60.0, 75.0, 58.0));
        let mut vol = Volume::<f32>::zeros(&[60, 50, 40], affine);
        for (i, v) in vol.data.iter_mut().enumerate() {
            *v = f32::from(u8::from((28..34).contains(&(i % 60))));
        }
        let tmp_mask = tempfile::tempdir().unwrap();
        let mask = tmp_mask.path().join("fascicle-mask.nii.gz");
        fascicle_core::io::nifti::write(&mask, &vol, fascicle_core::io::nifti::WriteType::F32).unwrap();
        let region = Region::Mask(Arc::new(MaskRegion::new(&vol)));
        let through: Vec<bool> = (0..t.n_streamlines())
            .map(|s| Criteria { include: vec![region.clone()], ..Default::default() }.keeps(t.streamline(s)))
            .collect();
        let n_through = through.iter().filter(|k| **k).count();
        assert!(n_through > 20 && n_through < t.n_streamlines() - 20, "{n_through} of {}", t.n_streamlines());
        let layer_ends = |mode, colouring, ends_only| LayerKind::Tracts {
            source: TractSource::File { path: path.clone(), tensors: None },
            mode: TractMode::Lines,
            render: Default::default(),
            rois: vec![],
            masks: vec![MaskRoi { path: mask.clone(), mode, crop: false, painted: None }],
            ends_only,
            deleted: vec![],
            colouring,
        };
        let layer = |mode, colouring| layer_ends(mode, colouring, false);
        // What the layer shows: the streamlines built, narrowed by its include and exclude masks as the tract
        // plugin narrows them (`TractMasks`, read by `mask_regions`).
        let built = |kind: &LayerKind| {
            let cache = DataCache::default();
            let t = match build(kind, &cache, &JobProgress::default()) {
                Ok(Content::Tracts(p)) => p.tractogram.expect("streamlines kept"),
                Ok(_) => panic!("not one set"),
                Err(e) => panic!("{e}"),
            };
            let LayerKind::Tracts { masks, ends_only, .. } = kind else { unreachable!() };
            let mut shown = vec![true; t.n_streamlines()];
            mask_regions(&cache, masks).unwrap_or_else(|e| panic!("{e}")).narrow(&t, *ends_only, &mut shown);
            t.subset(&shown)
        };
        let kept = |mode, colouring| built(&layer(mode, colouring));
        let first_points = |t: &Tractogram, keep: &dyn Fn(usize) -> bool| -> Vec<[f32; 3]> {
            (0..t.n_streamlines()).filter(|s| keep(*s)).map(|s| t.streamline(s)[0].to_array()).collect()
        };
        let inc = kept(RoiMode::Include, TractColouring::Style);
        assert_eq!(first_points(&inc, &|_| true), first_points(&t, &|s| through[s]));
        let exc = kept(RoiMode::Exclude, TractColouring::Style);
        assert_eq!(first_points(&exc, &|_| true), first_points(&t, &|s| !through[s]));
        // The same voxels painted in the viewer (no file is read): the same streamlines; nothing painted: all.
        let with_painted = |p: crate::model::PaintedMask| LayerKind::Tracts {
            source: TractSource::File { path: path.clone(), tensors: None },
            mode: TractMode::Lines,
            render: Default::default(),
            rois: vec![],
            masks: vec![MaskRoi {
                path: "never-written.nii.gz".into(),
                mode: RoiMode::Include,
                crop: false,
                painted: Some(p),
            }],
            ends_only: false,
            deleted: vec![],
            colouring: TractColouring::Style,
        };
        let mut painted = crate::model::PaintedMask::on_grid([60, 50, 40], affine);
        painted.paint((0..vol.data.len() as u32).filter(|&i| vol.data[i as usize] > 0.0), false);
        // Erasing what was never painted changes nothing; painting twice counts once.
        painted.paint([0, 1, 2], true);
        painted.paint([29, 29 + 60], false);
        assert_eq!(painted.voxels.len(), vol.data.iter().filter(|v| **v > 0.0).count());
        assert_eq!(painted.volume().data, vol.data);
        let by_painting = built(&with_painted(painted));
        assert_eq!(first_points(&by_painting, &|_| true), first_points(&inc, &|_| true));
        let nothing = crate::model::PaintedMask::on_grid([60, 50, 40], affine);
        assert_eq!(built(&with_painted(nothing)).n_streamlines(), t.n_streamlines());
        // A cutting mask (tckedit -mask): every streamline's runs of two or more points in the slab.
        let cutting = |colouring| LayerKind::Tracts {
            source: TractSource::File { path: path.clone(), tensors: None },
            mode: TractMode::Lines,
            render: Default::default(),
            rois: vec![],
            masks: vec![MaskRoi { path: mask.clone(), mode: RoiMode::Include, crop: true, painted: None }],
            ends_only: false,
            deleted: vec![],
            colouring,
        };
        let cut = built(&cutting(TractColouring::Style));
        // A point is in the slab when the streamline of that one point meets the region.
        let in_slab = |p: &glam::Vec3| Criteria { include: vec![region.clone()], ..Default::default() }.keeps(&[*p]);
        let mut want = Tractogram::new();
        for s in 0..t.n_streamlines() {
            let pts = t.streamline(s);
            let mut run: Vec<glam::Vec3> = vec![];
            for p in pts.iter().chain([&glam::Vec3::NAN]) {
                if in_slab(p) {
                    run.push(*p);
                } else {
                    if run.len() >= 2 {
                        want.push(&run);
                    }
                    run.clear();
                }
            }
        }
        assert!(want.n_streamlines() > 20, "{} pieces", want.n_streamlines());
        assert_eq!((&cut.offsets, &cut.points), (&want.offsets, &want.points));
        // Cut and coloured by a value per streamline (weights s / n): each piece in viridis of its streamline's
        // weight, as tckedit's pieces keep their streamline's weight.
        {
            use bevy::mesh::VertexAttributeValues;
            let tmp_w = tempfile::tempdir().unwrap();
            let wfile = tmp_w.path().join("fascicle-cut-weights.txt");
            let n = t.n_streamlines();
            let w: Vec<f32> = (0..n).map(|s| s as f32 / n as f32).collect();
            fascicle_core::io::weights::write(&wfile, &w).unwrap();
            let colouring =
                TractColouring::Value { weights: Some(wfile), name: String::new(), window: (0.0, 1.0), min: None };
            let Ok(Content::Tracts(p)) = build(&cutting(colouring), &DataCache::default(), &JobProgress::default())
            else {
                panic!("a cut layer coloured by values")
            };
            let source_of: Vec<usize> = (0..n)
                .flat_map(|s| {
                    let pieces = fascicle_core::roi::pieces_inside(t.streamline(s), std::slice::from_ref(&region));
                    std::iter::repeat_n(s, pieces.len())
                })
                .collect();
            assert_eq!(source_of.len(), want.n_streamlines());
            let fascicle_tracts::PreparedGeometry::Mesh { mesh, .. } = p.geometry else { panic!("not a mesh") };
            let (Some(VertexAttributeValues::Unorm8x4(col)), Some(VertexAttributeValues::Uint32(owners))) = (
                mesh.attribute(fascicle_tracts::ATTRIBUTE_RGBA8),
                mesh.attribute(fascicle_tracts::ATTRIBUTE_STREAMLINE),
            ) else {
                panic!("colours and streamlines")
            };
            let drawn: std::collections::BTreeSet<u32> = owners.iter().copied().collect();
            assert_eq!(drawn.len(), want.n_streamlines(), "every piece drawn");
            for (c, &k) in col.iter().zip(owners) {
                let s = source_of[k as usize];
                let want = fascicle_core::dti::splat::viridis(f64::from(w[s])).as_vec3();
                let got = glam::Vec3::from(c.map(|x| f32::from(x) / 255.0)[..3].try_into().unwrap_or([0.0; 3]));
                assert!((got - want).abs().max_element() < 0.5 / 255.0 + 1e-5, "piece {k} of streamline {s}: {c:?}");
            }
        }
        // Ends only (tckedit's -ends_only): the streamlines with an end in the slab, fewer than those through it.
        let ends: Vec<bool> = (0..t.n_streamlines())
            .map(|s| {
                let criteria = Criteria { include: vec![region.clone()], ends_only: true, ..Default::default() };
                criteria.keeps(t.streamline(s))
            })
            .collect();
        let ends_kept = built(&layer_ends(RoiMode::Include, TractColouring::Style, true));
        assert_eq!(first_points(&ends_kept, &|_| true), first_points(&t, &|s| ends[s]));
        assert!(ends_kept.n_streamlines() < n_through, "{} with an end in the slab", ends_kept.n_streamlines());
        // With weights s / n and a threshold of 0.5: the streamlines through the slab in the upper half.
        let tmp_weights = tempfile::tempdir().unwrap();
        let weights = tmp_weights.path().join("fascicle-mask-weights.txt");
        let n = t.n_streamlines();
        fascicle_core::io::weights::write(&weights, &(0..n).map(|s| s as f32 / n as f32).collect::<Vec<_>>()).unwrap();
        let value = TractColouring::Value {
            weights: Some(weights.clone()),
            name: String::new(),
            window: (0.0, 1.0),
            min: Some(0.5),
        };
        let both = kept(RoiMode::Include, value);
        assert_eq!(first_points(&both, &|_| true), first_points(&t, &|s| through[s] && s * 2 >= n));
        // An empty mask: an error naming it.
        vol.data.iter_mut().for_each(|v| *v = 0.0);
        fascicle_core::io::nifti::write(&mask, &vol, fascicle_core::io::nifti::WriteType::F32).unwrap();
        let LayerKind::Tracts { masks: empty, .. } = layer(RoiMode::Include, TractColouring::Style) else {
            unreachable!()
        };
        let e = mask_regions(&DataCache::default(), &empty).err().unwrap();
        assert!(e.contains(&mask.display().to_string()) && e.contains("empty"), "{e}");
        std::fs::remove_file(&mask).ok();
        std::fs::remove_file(&weights).ok();
    }

    /// The values' histogram: finite values only, the highest in the last bin, one value or none.
    #[test]
    fn value_histogram_counts_finite_values() {
        let h = ValueHistogram::of(&[0.0, 1.0, f32::NAN, f32::INFINITY, 0.25, 0.5]);
        assert_eq!(h.range, (0.0, 1.0));
        assert_eq!(h.counts.len(), VALUE_BINS);
        assert_eq!(h.counts.iter().sum::<u32>(), 4);
        assert_eq!(
            (h.counts[0], h.counts[VALUE_BINS / 4], h.counts[VALUE_BINS / 2], h.counts[VALUE_BINS - 1]),
            (1, 1, 1, 1)
        );
        let one = ValueHistogram::of(&[2.5, 2.5, f32::NAN]);
        assert_eq!((one.range, one.counts[0], one.counts.iter().sum::<u32>()), ((2.5, 2.5), 2, 2));
        let none = ValueHistogram::of(&[f32::NAN]);
        assert_eq!((none.range, none.counts.iter().sum::<u32>()), ((0.0, 0.0), 0));
    }

    /// A tensor file in FSL's or MRtrix3's element order reads as the same field as DIPY's.
    #[test]
    fn tensor_files_in_other_orders_read_as_dipy() {
        use fascicle_core::io::classify::TensorOrder;
        let cache = DataCache::default();
        let p = JobProgress::default();
        let path = data("dti/small_64D_tensor.nii.gz");
        let dipy =
            tensor_field(&cache, &TensorSource::Nifti { path: path.clone(), order: TensorOrder::Dipy }, &p).unwrap();
        let tmp_dir = tempfile::Builder::new().prefix("fascicle-orders-").tempdir().unwrap();
        let dir = tmp_dir.path().to_path_buf();
        for order in [TensorOrder::Fsl, TensorOrder::Mrtrix] {
            let mut v = (*dipy.tensors).clone();
            let n = v.n_voxels();
            for (slot, &dst) in order.dipy_slots().iter().enumerate() {
                v.data[dst * n..(dst + 1) * n].copy_from_slice(&dipy.tensors.data[slot * n..(slot + 1) * n]);
            }
            let out = dir.join(format!("{order:?}.nii.gz"));
            fascicle_core::io::nifti::write(&out, &v, fascicle_core::io::nifti::WriteType::F32).unwrap();
            let source = crate::model::tensor_source_for(&out);
            assert_eq!(source, TensorSource::Nifti { path: out.clone(), order });
            assert_eq!(tensor_field(&cache, &source, &p).unwrap().tensors.data, dipy.tensors.data);
        }
    }

    /// The slices placed ahead are the ones next to the layer's, inside the grid; free planes and full
    /// volumes have none.
    #[test]
    fn neighbour_slices_stay_in_the_grid() {
        let layer = |index| LayerKind::ShGlyphs {
            source: ShSource::PhantomCsa { l_max: 4 },
            axis: SliceAxis::Y,
            index,
            spacing: 1,
            plane: None,
            sampling: Default::default(),
            full_volume: false,
            style: Default::default(),
            render: Default::default(),
        };
        let indices = |k| -> Vec<Option<usize>> {
            neighbour_slices(&layer(k), [4, 6, 8])
                .iter()
                .map(|n| match n {
                    LayerKind::ShGlyphs { index, .. } => *index,
                    _ => unreachable!(),
                })
                .collect()
        };
        assert_eq!(indices(None), vec![Some(2), Some(4)], "the middle of 6 is 3");
        assert_eq!(indices(Some(0)), vec![Some(1)]);
        assert_eq!(indices(Some(5)), vec![Some(4)]);
        let mut volume = layer(None);
        if let LayerKind::ShGlyphs { full_volume, .. } = &mut volume {
            *full_volume = true;
        }
        assert!(neighbour_slices(&volume, [4, 6, 8]).is_empty());
    }

    /// A cancelled job stops at its next stage with [`CANCELLED`], and a stage's progress is the fraction of
    /// its units done.
    #[test]
    fn jobs_report_progress_and_stop_when_cancelled() {
        let p = JobProgress::default();
        p.stage("fitting", 200).unwrap();
        p.advance(50);
        assert_eq!(p.snapshot(), ("fitting", Some(0.25)));
        p.cancel();
        assert_eq!(p.stage("next", 0), Err(CANCELLED.to_string()));
        let kind = LayerKind::Tracts {
            source: TractSource::PhantomRk4 { seed_spacing: 4 },
            mode: Default::default(),
            render: Default::default(),
            rois: vec![],
            masks: vec![],
            ends_only: false,
            deleted: vec![],
            colouring: Default::default(),
        };
        assert_eq!(build(&kind, &DataCache::default(), &p).err(), Some(CANCELLED.to_string()));
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
        let tmp_dir = tempfile::Builder::new().prefix("fascicle-peak-layer-").tempdir().unwrap();
        let dir = tmp_dir.path().to_path_buf();
        let path = dir.join("csa_peaks.nii.gz");
        fascicle_core::io::peaks::write_mrtrix(&path, &peaks, affine).unwrap();
        let spec = crate::model::Scene::layer_for_file(&path).unwrap();
        assert!(
            matches!(
                &spec.kind,
                LayerKind::Tracts { source: TractSource::Peaks { .. }, mode: crate::model::TractMode::Lines, .. }
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
    }
}
