//! Per-layer parameter panels. Each layer kind contributes its own egui controls through [`LayerPanels`]; the
//! viewer's layer list shows, under each layer, the first panel whose `applies` accepts the layer's kind.
//! A glyph plugin's integration registers its panel the same way as the built-in ones below.

use bevy::prelude::*;
use bevy_egui::egui;
use fascicle_core::dti::barycentric::BarycentricTf;
use fascicle_core::dti::metrics::WestinDenominator;
use fascicle_core::dti::splat::SplatColourMode;
use fascicle_core::dvr::{TfPoint, TransferFunction};

use fascicle_core::dti::glyph::TensorShape;
use fascicle_core::sh::glyph::{GlyphPlane, Lobes, Normalise, Sampling};
use fascicle_sh_glyphs::{GlyphColour, GlyphMethod};
use fascicle_tensors::TensorColour;

use fascicle_scene::jobs::ValueHistogram;
use fascicle_scene::layers::LayerData;
use fascicle_scene::model::{LayerKind, ShSource, SliceAxis, TractColouring};

/// One layer kind's controls: `show` edits the kind in place (an edit re-syncs the layer); `data` is what
/// the layer's spawned entities report back (e.g. the samples' eigenvalues for a scattergram).
#[derive(Clone, Copy)]
pub struct LayerPanel {
    /// Short name of the panel (e.g. `slice`, `tensor glyphs`); not shown in the viewer.
    pub name: &'static str,
    /// Whether the panel edits a layer of this kind.
    pub applies: fn(&LayerKind) -> bool,
    /// Draws the controls, editing the kind in place, given what the layer reported.
    pub show: fn(&mut egui::Ui, &mut LayerKind, &LayerData),
}

/// The registry of layer panels.
#[derive(Resource, Clone)]
pub struct LayerPanels(pub Vec<LayerPanel>);

impl Default for LayerPanels {
    /// The built-in kinds' panels.
    fn default() -> Self {
        Self(vec![
            LayerPanel { name: "slice", applies: |k| matches!(k, LayerKind::Slice { .. }), show: slice_panel },
            LayerPanel {
                name: "tractogram",
                applies: |k| matches!(k, LayerKind::Tractogram { .. }),
                show: tractogram_panel,
            },
            LayerPanel { name: "axes", applies: |k| matches!(k, LayerKind::Axes { .. }), show: axes_panel },
            LayerPanel { name: "sh glyphs", applies: |k| matches!(k, LayerKind::ShGlyphs { .. }), show: glyph_panel },
            LayerPanel {
                name: "tensor splats",
                applies: |k| matches!(k, LayerKind::TensorSplats { .. }),
                show: splat_panel,
            },
            LayerPanel { name: "volume", applies: |k| matches!(k, LayerKind::Volume { .. }), show: volume_panel },
            LayerPanel { name: "tracts", applies: |k| matches!(k, LayerKind::Tracts { .. }), show: tracts_panel },
            LayerPanel {
                name: "tensor glyphs",
                applies: |k| matches!(k, LayerKind::TensorGlyphs { .. }),
                show: tensor_panel,
            },
        ])
    }
}

impl LayerPanels {
    /// Adds a panel; later registrations take precedence over earlier ones for the same kind.
    pub fn register(&mut self, panel: LayerPanel) {
        self.0.insert(0, panel);
    }

    /// The panel for a kind, if any.
    pub fn find(&self, kind: &LayerKind) -> Option<&LayerPanel> {
        self.0.iter().find(|p| (p.applies)(kind))
    }
}

fn slice_panel(ui: &mut egui::Ui, kind: &mut LayerKind, _: &LayerData) {
    let LayerKind::Slice { axis, index, window, .. } = kind else { return };
    slice_controls(ui, axis, index);
    // Window/level: also a right-drag in a 2D view.
    ui.horizontal(|ui| {
        let mut auto = window.is_none();
        if ui.checkbox(&mut auto, "auto window").changed() {
            *window = if auto { None } else { Some((0.0, 1.0)) };
        }
        if let Some((lo, hi)) = window {
            let speed = f64::from((*hi - *lo).abs().max(1e-6)) * 0.005;
            ui.add(egui::DragValue::new(lo).speed(speed).prefix("black "));
            ui.add(egui::DragValue::new(hi).speed(speed).prefix("white "));
        }
    });
}

/// The slice of a slice, glyph or tensor layer: its axis and index (the middle one when unset).
fn slice_controls(ui: &mut egui::Ui, axis: &mut SliceAxis, index: &mut Option<usize>) {
    ui.horizontal(|ui| {
        for (a, label) in [(SliceAxis::X, "sagittal"), (SliceAxis::Y, "coronal"), (SliceAxis::Z, "axial")] {
            ui.radio_value(axis, a, label);
        }
    });
    ui.horizontal(|ui| {
        let mut middle = index.is_none();
        if ui.checkbox(&mut middle, "middle").changed() {
            *index = if middle { None } else { Some(0) };
        }
        if let Some(i) = index {
            ui.add(egui::DragValue::new(i).range(0..=4096).prefix("slice "));
        }
    });
}

/// SH glyphs: plane, size and shape (rebuild the glyphs), then the ray caster's knobs and colour (a uniform
/// update only).
fn glyph_panel(ui: &mut egui::Ui, kind: &mut LayerKind, _: &LayerData) {
    let LayerKind::ShGlyphs { source, axis, index, spacing, plane, sampling, full_volume, style, render } = kind else {
        return;
    };
    ui.label(match source {
        ShSource::PhantomCsa { l_max } => format!("phantom CSA, l_max {l_max}"),
        ShSource::Nifti { path, basis } => format!("{} ({})", path.display(), basis.name()),
    });
    ui.checkbox(full_volume, "whole volume");
    let mut free = plane.is_some();
    if *full_volume {
        ui.add(egui::Slider::new(spacing, 1..=8).text("spacing (voxels)"));
    } else if ui.checkbox(&mut free, "free plane").changed() {
        *plane =
            free.then_some(GlyphPlane { centre: [0.0; 3], normal: [0.0, 0.0, 1.0], half_size: 48.0, spacing: 2.0 });
    }
    if *full_volume {
    } else if let Some(p) = plane {
        ui.horizontal(|ui| {
            ui.label("centre");
            for c in p.centre.iter_mut() {
                ui.add(egui::DragValue::new(c).speed(0.5));
            }
        });
        ui.horizontal(|ui| {
            ui.label("normal");
            for c in p.normal.iter_mut() {
                ui.add(egui::DragValue::new(c).speed(0.02).range(-1.0..=1.0));
            }
        });
        ui.add(egui::Slider::new(&mut p.half_size, 1.0..=200.0).text("half size (mm)"));
        ui.add(egui::Slider::new(&mut p.spacing, 0.25..=10.0).text("spacing (mm)"));
        ui.horizontal(|ui| {
            ui.radio_value(sampling, Sampling::Nearest, "nearest");
            ui.radio_value(sampling, Sampling::Trilinear, "trilinear");
        });
    } else {
        slice_controls(ui, axis, index);
        ui.add(egui::Slider::new(spacing, 1..=8).text("spacing (voxels)"));
    }
    match &mut style.cell_fill {
        Some(fill) => {
            ui.add(egui::Slider::new(fill, 0.1..=2.0).text("size (fraction of the grid spacing)"));
        }
        None => {
            ui.add(egui::Slider::new(&mut style.scale, 0.1..=10.0).text("size (mm)"));
        }
    }
    ui.checkbox(&mut style.fit_lobes, "size by the largest lobe");
    ui.add(egui::Slider::new(&mut style.sharpen, 1.0..=10.0).text("sharpening"));
    ui.horizontal(|ui| {
        ui.radio_value(&mut style.normalise, Normalise::PerGlyph, "per glyph");
        ui.radio_value(&mut style.normalise, Normalise::Global, "global");
        ui.radio_value(&mut style.normalise, Normalise::A00, "a00 (GFA shows)");
        ui.radio_value(&mut style.normalise, Normalise::MinMax, "min-max");
    });
    ui.horizontal(|ui| {
        ui.radio_value(&mut render.method, GlyphMethod::Exact, "exact");
        ui.radio_value(&mut render.method, GlyphMethod::Linear, "linear search (seed)");
    });
    match render.method {
        GlyphMethod::Exact => {
            ui.add(egui::Slider::new(&mut render.samples, 4..=256).logarithmic(true).text("root samples"));
        }
        GlyphMethod::Linear => {
            ui.add(egui::Slider::new(&mut render.h, 0.002..=0.2).logarithmic(true).text("step h (rmax)"));
        }
    }
    ui.add(egui::Slider::new(&mut render.refine, 0..=24).text("bisections"));
    ui.horizontal(|ui| {
        ui.radio_value(&mut render.lobes, Lobes::Clamp, "clamp negative");
        ui.radio_value(&mut render.lobes, Lobes::Abs, "|psi|, mark negative");
    });
    ui.horizontal(|ui| {
        ui.radio_value(&mut render.colour, GlyphColour::Direction, "direction");
        ui.radio_value(&mut render.colour, GlyphColour::Grey, "grey");
        ui.radio_value(&mut render.colour, GlyphColour::Gfa, "GFA");
        ui.radio_value(&mut render.colour, GlyphColour::Normal, "normal");
    });
    ui.add(egui::Slider::new(&mut render.specular, 0.0..=1.0).text("specular"));
}

/// Tensor splats: slab and size (rebuild), attenuation and opacity (uniform only).
fn splat_panel(ui: &mut egui::Ui, kind: &mut LayerKind, data: &LayerData) {
    let LayerKind::TensorSplats { source, axis, index, thickness, size, min_fa, render, .. } = kind else { return };
    bvec_convention_field(ui, source);
    slice_controls(ui, axis, index);
    ui.add(egui::Slider::new(thickness, 1..=15).text("slab (slices)"));
    ui.add(egui::Slider::new(size, 0.1..=2.0).text("size (voxels)"));
    ui.add(egui::Slider::new(min_fa, 0.0..=1.0).text("min FA"));
    ui.checkbox(&mut render.attenuation, "depth attenuation");
    ui.add(egui::Slider::new(&mut render.opacity, 0.0..=2.0).text("opacity"));
    ui.checkbox(&mut render.lit, "lit-tensor shading");
    ui.horizontal(|ui| {
        let mode = &mut render.colouring.mode;
        ui.radio_value(mode, SplatColourMode::Fa, "FA");
        ui.radio_value(mode, SplatColourMode::Direction, "direction");
        ui.radio_value(mode, SplatColourMode::Barycentric, "barycentric");
    });
    if render.colouring.mode == SplatColourMode::Barycentric {
        barycentric_widget(ui, &mut render.colouring.tf, &data.eigenvalues);
    }
}

/// Tracts: mode, cross-section scale and colour (rebuild); iterations and tolerance (uniform); ROIs
/// (re-selection only).
/// The tensor image that gives a file's streamlines their sections: a path, `phantom`, or empty for none.
/// Applied when the field loses focus (Enter), not at every keystroke, since a change reloads the layer.
fn tensor_source_field(ui: &mut egui::Ui, tensors: &mut Option<fascicle_scene::model::TensorSource>) {
    use fascicle_scene::model::TensorSource;
    let shown = |t: &Option<TensorSource>| match t {
        Some(TensorSource::Nifti { path, .. } | TensorSource::Dwi { path, .. }) => path.display().to_string(),
        Some(TensorSource::Phantom) => "phantom".into(),
        Some(TensorSource::Spiral { n }) => format!("spiral {n}"),
        None => String::new(),
    };
    let id = ui.id().with("tensor-source");
    let mut text = ui.data_mut(|d| d.get_temp::<String>(id)).unwrap_or_else(|| shown(tensors));
    ui.horizontal(|ui| {
        ui.label("sections from tensors");
        let r = ui.add(egui::TextEdit::singleline(&mut text).hint_text("tensor .nii.gz, phantom, or none"));
        if r.lost_focus() {
            *tensors = tensor_source_from_text(&text);
        }
    });
    ui.data_mut(|d| d.insert_temp(id, text));
}

/// What the tensor field's text means: empty for none, `phantom` for the built-in phantom, else a path.
fn tensor_source_from_text(text: &str) -> Option<fascicle_scene::model::TensorSource> {
    use fascicle_scene::model::TensorSource;
    match text.trim() {
        "" => None,
        "phantom" => Some(TensorSource::Phantom),
        path => Some(fascicle_scene::model::tensor_source_for(std::path::Path::new(path))),
    }
}

/// How a tract layer is coloured: the style's own (direction, Westin, per streamline), endpoints, length or a
/// scalar image sampled along the streamlines (a NIfTI or .mif path, one volume, a window).
fn tract_colouring(
    ui: &mut egui::Ui,
    colouring: &mut TractColouring,
    render: &mut fascicle_tracts::TubeSettings,
    data: &LayerData,
) {
    use fascicle_core::tubelet::TubeColour;
    ui.horizontal(|ui| {
        ui.label("colour");
        for (c, name) in
            [(TubeColour::Direction, "direction"), (TubeColour::Westin, "Westin"), (TubeColour::Streamline, "random")]
        {
            if ui.radio(*colouring == TractColouring::Style && render.colour == c, name).clicked() {
                *colouring = TractColouring::Style;
                render.colour = c;
            }
        }
        if ui.radio(*colouring == TractColouring::Ends, "ends").clicked() {
            *colouring = TractColouring::Ends;
        }
        if ui.radio(matches!(colouring, TractColouring::Length { .. }), "length").clicked()
            && !matches!(colouring, TractColouring::Length { .. })
        {
            *colouring = TractColouring::Length { max_mm: 150.0 };
        }
        if ui.radio(matches!(colouring, TractColouring::Scalar { .. }), "scalar image").clicked()
            && !matches!(colouring, TractColouring::Scalar { .. })
        {
            *colouring = TractColouring::Scalar {
                source: fascicle_scene::model::VolumeSource::Nifti { path: Default::default(), volume: 0 },
                window: (0.0, 1.0),
            };
        }
        if ui
            .radio(matches!(colouring, TractColouring::Value { .. }), "value")
            .on_hover_text(
                "a value per streamline: a tcksift2 weights file, or the file's own per-streamline array (TRX dps)",
            )
            .clicked()
            && !matches!(colouring, TractColouring::Value { .. })
        {
            *colouring = TractColouring::Value { weights: None, name: String::new(), window: (0.0, 1.0), min: None };
        }
        if ui
            .radio(matches!(colouring, TractColouring::PointValue { .. }), "value per point")
            .on_hover_text(
                "a value per point: an MRtrix .tsf file (tcksample), or the file's own per-point array (TRX dpp)",
            )
            .clicked()
            && !matches!(colouring, TractColouring::PointValue { .. })
        {
            *colouring = TractColouring::PointValue { file: None, name: String::new(), window: (0.0, 1.0) };
        }
    });
    match colouring {
        TractColouring::Length { max_mm } => {
            ui.add(egui::Slider::new(max_mm, 5.0..=300.0).text("length at the top of the map (mm)"));
        }
        TractColouring::Scalar { source: fascicle_scene::model::VolumeSource::Nifti { path, volume }, window } => {
            let mut text = path.display().to_string();
            ui.horizontal(|ui| {
                ui.label("image");
                if ui.text_edit_singleline(&mut text).changed() {
                    *path = text.into();
                }
            });
            ui.add(egui::DragValue::new(volume).prefix("volume "));
            window_row(ui, window);
        }
        TractColouring::Value { weights, name, window, min } => {
            values_source(ui, weights, name, ["weights file", "tcksift2 .txt, or empty", "per-streamline array"]);
            window_row(ui, window);
            let mut hide = min.is_some();
            let mut m = min.unwrap_or(window.0);
            ui.horizontal(|ui| {
                ui.checkbox(&mut hide, "hide below");
                ui.add_enabled(hide, egui::DragValue::new(&mut m).speed(0.01));
            });
            *min = hide.then_some(m);
            if let Some(values) = &data.values {
                value_histogram(ui, values, "streamlines", window, Some(min));
            }
        }
        TractColouring::PointValue { file, name, window } => {
            values_source(ui, file, name, ["track scalar file", ".tsf, or empty", "per-point array"]);
            window_row(ui, window);
            if let Some(values) = &data.values {
                value_histogram(ui, values, "points", window, None);
            }
        }
        _ => {}
    }
}

/// The two ends of a colour window.
fn window_row(ui: &mut egui::Ui, window: &mut (f32, f32)) {
    ui.horizontal(|ui| {
        ui.add(egui::DragValue::new(&mut window.0).speed(0.01).prefix("from "));
        ui.add(egui::DragValue::new(&mut window.1).speed(0.01).prefix("to "));
    });
}

/// Where a tract layer's values come from: a file (empty: none), else the tractogram's own array `name`.
/// `labels`: the file's label, its hint, the array's label.
fn values_source(ui: &mut egui::Ui, file: &mut Option<std::path::PathBuf>, name: &mut String, labels: [&str; 3]) {
    let mut text = file.as_ref().map(|p| p.display().to_string()).unwrap_or_default();
    ui.horizontal(|ui| {
        ui.label(labels[0]);
        if ui.add(egui::TextEdit::singleline(&mut text).hint_text(labels[1])).changed() {
            *file = (!text.trim().is_empty()).then(|| text.trim().into());
        }
    });
    if file.is_none() {
        ui.horizontal(|ui| {
            ui.label(labels[2]);
            ui.text_edit_singleline(name);
        });
    }
}

fn tracts_panel(ui: &mut egui::Ui, kind: &mut LayerKind, data: &LayerData) {
    use fascicle_core::roi::{Roi, RoiMode, RoiShape};
    use fascicle_scene::model::TractMode;
    let LayerKind::Tracts { source, mode, render, rois, masks, colouring, ends_only, deleted: _ } = kind else {
        return;
    };
    ui.horizontal(|ui| {
        ui.radio_value(mode, TractMode::Tubes, "hyperstreamlines");
        ui.radio_value(mode, TractMode::Polygon, "polygon tubes");
        ui.radio_value(mode, TractMode::Lines, "lines");
    });
    if let fascicle_scene::model::TractSource::File { tensors, .. } = source {
        tensor_source_field(ui, tensors);
    }
    if let fascicle_scene::model::TractSource::Peaks { length, .. } = source {
        ui.add(egui::Slider::new(length, 0.1..=2.0).text("peak length (voxels)"));
    }
    if let fascicle_scene::model::TractSource::Track { seeds, params, .. } = source {
        track_settings(ui, seeds, params);
    }
    ui.add(egui::Slider::new(&mut render.scale, 0.2..=6.0).text("cross-section scale (mm)"));
    ui.add(egui::Slider::new(&mut render.iterations, 1..=32).text("iterations"));
    tract_colouring(ui, colouring, render, data);
    ui.label("ROIs (a streamline shows when it meets every include and no exclude)");
    ui.checkbox(ends_only, "ends only: regions test each streamline's first and last points (tckedit -ends_only)");
    let mut remove = None;
    for (i, roi) in rois.iter_mut().enumerate() {
        ui.push_id(i, |ui| {
            ui.horizontal(|ui| {
                ui.radio_value(&mut roi.mode, RoiMode::Include, "include");
                ui.radio_value(&mut roi.mode, RoiMode::Exclude, "exclude");
                if ui.small_button("x").clicked() {
                    remove = Some(i);
                }
            });
            match &mut roi.shape {
                RoiShape::Sphere { centre, radius } => {
                    vec3_drag(ui, centre, "sphere at");
                    ui.add(egui::Slider::new(radius, 0.5..=60.0).text("radius (mm)"));
                }
                RoiShape::Box { min, max } => {
                    vec3_drag(ui, min, "box from");
                    vec3_drag(ui, max, "to");
                }
                RoiShape::Plane { point, normal } => {
                    vec3_drag(ui, point, "plane through");
                    vec3_drag(ui, normal, "normal");
                }
            }
        });
    }
    if let Some(i) = remove {
        rois.remove(i);
    }
    ui.horizontal(|ui| {
        let add = |shape| Roi { shape, mode: RoiMode::Include };
        if ui.button("+ sphere").clicked() {
            rois.push(add(RoiShape::Sphere { centre: [0.0; 3], radius: 10.0 }));
        }
        if ui.button("+ box").clicked() {
            rois.push(add(RoiShape::Box { min: [-10.0; 3], max: [10.0; 3] }));
        }
        if ui.button("+ plane").clicked() {
            rois.push(add(RoiShape::Plane { point: [0.0; 3], normal: [1.0, 0.0, 0.0] }));
        }
    });
    mask_rois(ui, masks);
}

/// A tract layer's mask images: each with include or exclude and a remove button; a path typed in the field is
/// added by the button (not at every keystroke: each change reads the masks again, and a cutting mask rebuilds the layer).
fn mask_rois(ui: &mut egui::Ui, masks: &mut Vec<fascicle_scene::model::MaskRoi>) {
    use fascicle_core::roi::RoiMode;
    let mut remove = None;
    for (i, m) in masks.iter_mut().enumerate() {
        ui.horizontal(|ui| {
            match &m.painted {
                Some(p) => ui.label(format!("painted {} voxels, saved as {}", p.voxels.len(), m.path.display())),
                None => ui.label(format!("mask {}", m.path.display())),
            };
            let mut use_ = if m.crop { None } else { Some(m.mode) };
            ui.radio_value(&mut use_, Some(RoiMode::Include), "include");
            ui.radio_value(&mut use_, Some(RoiMode::Exclude), "exclude");
            ui.radio_value(&mut use_, None, "cut").on_hover_text("tckedit -mask: streamlines cut where they leave it");
            m.crop = use_.is_none();
            if let Some(mode) = use_ {
                m.mode = mode;
            }
            if ui.small_button("x").clicked() {
                remove = Some(i);
            }
        });
    }
    if let Some(i) = remove {
        masks.remove(i);
    }
    let id = ui.id().with("new mask");
    let mut path = ui.data_mut(|d| d.get_temp::<String>(id)).unwrap_or_default();
    ui.horizontal(|ui| {
        ui.add(egui::TextEdit::singleline(&mut path).hint_text("mask .nii.gz / .mif").desired_width(180.0));
        if ui.button("+ mask").clicked() && !path.trim().is_empty() {
            masks.push(fascicle_scene::model::MaskRoi {
                path: path.trim().into(),
                mode: RoiMode::Include,
                crop: false,
                painted: None,
            });
            path.clear();
        }
    });
    ui.data_mut(|d| d.insert_temp(id, path));
}

/// A labelled row of three drag values (a point or direction in mm).
fn vec3_drag(ui: &mut egui::Ui, v: &mut [f32; 3], label: &str) {
    ui.horizontal(|ui| {
        ui.label(label);
        for c in v.iter_mut() {
            ui.add(egui::DragValue::new(c).speed(0.5));
        }
    });
}

/// Tracking: seeds (a grid over the field or a sphere) and the tracker's parameters; any change tracks again
/// (in the background).
fn track_settings(
    ui: &mut egui::Ui,
    seeds: &mut fascicle_scene::model::Seeds,
    params: &mut fascicle_core::tracking::TrackParams,
) {
    use fascicle_core::tracking::Integrator;
    use fascicle_scene::model::Seeds;
    ui.horizontal(|ui| {
        ui.label("seeds");
        if ui.radio(matches!(seeds, Seeds::Grid { .. }), "grid").clicked() && !matches!(seeds, Seeds::Grid { .. }) {
            *seeds = Seeds::default();
        }
        if ui.radio(matches!(seeds, Seeds::Sphere { .. }), "sphere").clicked() && !matches!(seeds, Seeds::Sphere { .. })
        {
            *seeds = Seeds::Sphere { centre: [0.0; 3], radius: 5.0, per_voxel: 8 };
        }
    });
    match seeds {
        Seeds::Grid { spacing, min_fa } => {
            ui.add(egui::Slider::new(spacing, 1..=8).text("every n-th voxel"));
            ui.add(egui::Slider::new(min_fa, 0.0..=0.9).text("seed FA at least"));
        }
        Seeds::Sphere { centre, radius, per_voxel } => {
            vec3_drag(ui, centre, "centre");
            ui.add(egui::Slider::new(radius, 0.5..=40.0).text("radius (mm)"));
            ui.add(egui::Slider::new(per_voxel, 1..=27).text("seeds per voxel"));
        }
    }
    ui.add(egui::Slider::new(&mut params.fa_threshold, 0.0..=0.9).text("stop below FA"));
    ui.add(egui::Slider::new(&mut params.max_angle_deg, 5.0..=90.0).text("max angle (deg)"));
    ui.add(egui::Slider::new(&mut params.step_mm, 0.1..=2.0).text("step (mm)"));
    ui.horizontal(|ui| {
        ui.radio_value(&mut params.integrator, Integrator::Euler, "Euler");
        ui.radio_value(&mut params.integrator, Integrator::Rk2, "RK2");
        ui.radio_value(&mut params.integrator, Integrator::Rk4, "RK4");
    });
}

/// Volume: method and step (rebuild), transfer function and toggles (buffers and uniform only).
fn volume_panel(ui: &mut egui::Ui, kind: &mut LayerKind, data: &LayerData) {
    use fascicle_volume::VolumeMethod;
    let LayerKind::Volume { render, .. } = kind else { return };
    ui.horizontal(|ui| {
        ui.radio_value(&mut render.method, VolumeMethod::Raycast, "ray casting");
        ui.radio_value(&mut render.method, VolumeMethod::Slicing, "3D-texture slicing");
        ui.radio_value(&mut render.method, VolumeMethod::Slicing2d, "2D slicing (voxel planes)");
    });
    ui.horizontal(|ui| {
        ui.radio_value(&mut render.method, VolumeMethod::Splatting, "voxel splatting");
        ui.radio_value(&mut render.method, VolumeMethod::Tetrahedra, "cell projection (tetrahedra)");
        ui.radio_value(&mut render.method, VolumeMethod::ShearWarp, "shear-warp");
    });
    match render.method {
        VolumeMethod::Splatting => {
            ui.add(egui::Slider::new(&mut render.kernel, 0.2..=2.0).text("kernel sigma (voxels)"));
        }
        VolumeMethod::Tetrahedra => {
            ui.add(egui::Slider::new(&mut render.cell, 1..=8).text("cell (voxels, 6 tetrahedra each)"));
        }
        VolumeMethod::ShearWarp => {
            ui.add(
                egui::Slider::new(&mut render.intermediate, 0.25..=4.0)
                    .logarithmic(true)
                    .text("intermediate image (pixels per voxel)"),
            );
        }
        _ => {}
    }
    ui.add(egui::Slider::new(&mut render.step, 0.05..=4.0).logarithmic(true).text("step / slice spacing (mm)"));
    let mut early = render.termination <= 1.0;
    ui.horizontal(|ui| {
        ui.checkbox(&mut early, "early termination");
        ui.checkbox(&mut render.jitter, "jitter / dither");
    });
    render.termination = if early { render.termination.min(0.99) } else { 2.0 };
    ui.horizontal(|ui| {
        ui.checkbox(&mut render.shading, "gradient shading");
        ui.checkbox(&mut render.preintegrated, "pre-integrated");
    });
    ui.collapsing("clip box (fraction of each voxel axis)", |ui| {
        for (k, axis) in ["i", "j", "k"].into_iter().enumerate() {
            ui.horizontal(|ui| {
                ui.label(axis);
                ui.add(egui::DragValue::new(&mut render.clip.min[k]).range(0.0..=1.0).speed(0.01));
                ui.add(egui::DragValue::new(&mut render.clip.max[k]).range(0.0..=1.0).speed(0.01));
            });
            if render.clip.min[k] > render.clip.max[k] {
                render.clip.min[k] = render.clip.max[k];
            }
        }
    });
    transfer_function_editor(ui, &mut render.tf, &data.histogram);
}

/// Draws `counts` as bars of log(1 + count) filling `rect` left to right, on a dark ground.
fn log_histogram(painter: &egui::Painter, rect: egui::Rect, counts: &[u32]) {
    painter.rect_filled(rect, 2.0, egui::Color32::from_gray(25));
    let peak = counts.iter().map(|c| (*c as f32 + 1.0).ln()).fold(0.0, f32::max).max(1.0);
    for (i, c) in counts.iter().enumerate() {
        let x0 = rect.left() + rect.width() * i as f32 / counts.len() as f32;
        let x1 = rect.left() + rect.width() * (i + 1) as f32 / counts.len() as f32;
        let y = rect.bottom() - rect.height() * (*c as f32 + 1.0).ln() / peak;
        painter.rect_filled(
            egui::Rect::from_min_max(egui::pos2(x0, y), egui::pos2(x1, rect.bottom())),
            0.0,
            egui::Color32::from_gray(60),
        );
    }
}

/// The values of a tract layer (per streamline or per point: `of` names them): their histogram (log counts)
/// with the colour window's ends (white) and, given `min`, the threshold (red; streamlines left of it hidden),
/// which a click sets there; a button fits the window to the values' range. Returns where the histogram was
/// drawn.
fn value_histogram(
    ui: &mut egui::Ui,
    values: &ValueHistogram,
    of: &str,
    window: &mut (f32, f32),
    mut min: Option<&mut Option<f32>>,
) -> egui::Rect {
    let (lo, hi) = values.range;
    let n: u64 = values.counts.iter().map(|c| u64::from(*c)).sum();
    ui.label(format!("{n} {of} with values from {lo:.4} to {hi:.4}"));
    let (resp, painter) = ui.allocate_painter(egui::vec2(220.0, 60.0), egui::Sense::click());
    let rect = resp.rect;
    log_histogram(&painter, rect, &values.counts);
    let span = if hi > lo { hi - lo } else { 1.0 };
    let x_of = |v: f32| rect.left() + rect.width() * ((v - lo) / span).clamp(0.0, 1.0);
    let mark = |v: f32, colour| {
        painter.line_segment(
            [egui::pos2(x_of(v), rect.top()), egui::pos2(x_of(v), rect.bottom())],
            egui::Stroke::new(1.5, colour),
        )
    };
    mark(window.0, egui::Color32::WHITE);
    mark(window.1, egui::Color32::WHITE);
    if let Some(&mut Some(m)) = min.as_deref_mut() {
        let hidden = egui::Rect::from_min_max(rect.left_top(), egui::pos2(x_of(m), rect.bottom()));
        painter.rect_filled(hidden, 0.0, egui::Color32::from_black_alpha(140));
        mark(m, egui::Color32::RED);
    }
    if resp.clicked()
        && let Some(p) = resp.interact_pointer_pos()
        && let Some(min) = min
    {
        *min = Some(lo + span * ((p.x - rect.left()) / rect.width()).clamp(0.0, 1.0));
    }
    if ui.button("fit the colour window to the values").clicked() && hi >= lo {
        *window = (lo, hi);
    }
    rect
}

/// The 1D transfer-function editor: the volume's histogram (log counts) under the opacity curve; each
/// control point is a handle to drag (value, opacity), with a colour button and a remove button; a click
/// on empty space adds a point there.
pub fn transfer_function_editor(ui: &mut egui::Ui, tf: &mut TransferFunction, histogram: &[u32]) {
    let (w, h) = (220.0f32, 90.0f32);
    let (resp, painter) = ui.allocate_painter(egui::vec2(w, h), egui::Sense::click_and_drag());
    let rect = resp.rect;
    log_histogram(&painter, rect, histogram);
    let max_a = tf.points.iter().map(|p| p.rgba[3]).fold(0.0, f64::max).max(0.05);
    let to_screen =
        |p: &TfPoint| egui::pos2(rect.left() + w * p.x as f32, rect.bottom() - h * (p.rgba[3] / max_a) as f32);
    tf.points.sort_by(|a, b| a.x.total_cmp(&b.x));
    let line: Vec<egui::Pos2> = tf.points.iter().map(to_screen).collect();
    painter.add(egui::Shape::line(line, egui::Stroke::new(1.5, egui::Color32::WHITE)));
    let mut grabbed = None;
    for (i, p) in tf.points.iter().enumerate() {
        let c = p.rgba.map(|v| (fascicle_render::reference::srgb8(v.clamp(0.0, 1.0))).round() as u8);
        let pos = to_screen(p);
        painter.circle_filled(pos, 4.0, egui::Color32::from_rgb(c[0], c[1], c[2]));
        painter.circle_stroke(pos, 4.0, egui::Stroke::new(1.0, egui::Color32::WHITE));
        if let Some(q) = resp.interact_pointer_pos()
            && resp.drag_started()
            && q.distance(pos) < 8.0
        {
            grabbed = Some(i);
        }
    }
    let id = resp.id.with("grabbed");
    if let Some(i) = grabbed {
        ui.data_mut(|d| d.insert_temp(id, i));
    }
    if resp.drag_stopped() {
        ui.data_mut(|d| d.remove::<usize>(id));
    }
    let held: Option<usize> = ui.data(|d| d.get_temp(id));
    if let (Some(i), Some(q)) = (held, resp.interact_pointer_pos())
        && resp.dragged()
        && i < tf.points.len()
    {
        tf.points[i].x = ((q.x - rect.left()) / w).clamp(0.0, 1.0) as f64;
        tf.points[i].rgba[3] = (((rect.bottom() - q.y) / h).clamp(0.0, 1.0) as f64) * max_a;
    } else if resp.clicked()
        && let Some(q) = resp.interact_pointer_pos()
    {
        let x = ((q.x - rect.left()) / w).clamp(0.0, 1.0) as f64;
        let mut rgba = tf.eval_normalised(x);
        rgba[3] = (((rect.bottom() - q.y) / h).clamp(0.0, 1.0) as f64) * max_a;
        tf.points.push(TfPoint { x, rgba });
    }
    let mut remove = None;
    for (i, p) in tf.points.iter_mut().enumerate() {
        ui.horizontal(|ui| {
            let mut c = [p.rgba[0] as f32, p.rgba[1] as f32, p.rgba[2] as f32];
            if ui.color_edit_button_rgb(&mut c).changed() {
                p.rgba[..3].copy_from_slice(&c.map(f64::from));
            }
            ui.add(egui::DragValue::new(&mut p.x).range(0.0..=1.0).speed(0.005).prefix("at "));
            ui.add(egui::DragValue::new(&mut p.rgba[3]).range(0.0..=1.0).speed(0.005).prefix("opacity/mm "));
            if ui.small_button("x").clicked() {
                remove = Some(i);
            }
        });
    }
    if let Some(i) = remove.filter(|_| tf.points.len() > 2) {
        tf.points.remove(i);
    }
    ui.horizontal(|ui| {
        ui.label("window");
        ui.add(egui::DragValue::new(&mut tf.range[0]).speed(0.01));
        ui.add(egui::DragValue::new(&mut tf.range[1]).speed(0.01));
    });
}

/// Triangle corners in widget units (side 1, y down): linear bottom left, planar bottom right, spherical top.
const TRI: [[f32; 2]; 3] = [[0.0, 0.866], [1.0, 0.866], [0.5, 0.0]];

/// The barycentric transfer-function editor (SEEDS.md §1): the cl/cp/cs triangle shaded with the corner
/// colours, a scattergram of the samples, the bump's centre as a circle of its width (drag or click to move
/// it), sliders for width, threshold and opacity, invert and stretch, the denominator, a colour per corner.
pub fn barycentric_widget(ui: &mut egui::Ui, tf: &mut BarycentricTf, eigenvalues: &[[f64; 3]]) {
    let side = 200.0f32;
    let (resp, painter) =
        ui.allocate_painter(egui::vec2(side + 16.0, side * 0.866 + 16.0), egui::Sense::click_and_drag());
    let origin = resp.rect.min + egui::vec2(8.0, 8.0);
    let to_screen = |w: [f64; 3]| {
        let t = w.iter().sum::<f64>().max(1e-12);
        let (x, y) =
            (0..3).fold((0.0, 0.0), |(x, y), k| (x + TRI[k][0] as f64 * w[k] / t, y + TRI[k][1] as f64 * w[k] / t));
        origin + egui::vec2(x as f32 * side, y as f32 * side)
    };
    let colour = |c: [f64; 3]| {
        let g = |v: f64| (fascicle_render::reference::srgb8(v.clamp(0.0, 1.0))).round() as u8;
        egui::Color32::from_rgb(g(c[0]), g(c[1]), g(c[2]))
    };
    let mut mesh = egui::Mesh::default();
    for k in 0..3 {
        let mut w = [0.0; 3];
        w[k] = 1.0;
        mesh.colored_vertex(to_screen(w), colour(tf.corners[k]).gamma_multiply(0.6));
    }
    mesh.add_triangle(0, 1, 2);
    painter.add(egui::Shape::mesh(mesh));
    let measures: Vec<[f64; 3]> = eigenvalues.iter().map(|l| tf.measures(l)).collect();
    let ranges = fascicle_core::dti::barycentric::ranges(&measures);
    for m in &measures {
        let (_, a) = tf.eval(*m, Some(&ranges));
        let shown = if tf.stretch { stretch(*m, &ranges) } else { *m };
        let grey = (80.0 + 175.0 * a) as u8;
        painter.circle_filled(to_screen(shown), 1.2, egui::Color32::from_gray(grey));
    }
    let centre = to_screen(tf.centre);
    painter.circle_stroke(centre, (tf.width as f32 * side).max(2.0), egui::Stroke::new(1.5, egui::Color32::WHITE));
    painter.circle_filled(centre, 3.0, egui::Color32::WHITE);
    for (k, label) in ["linear", "planar", "spherical"].iter().enumerate() {
        let mut w = [0.0; 3];
        w[k] = 1.0;
        let anchor = [egui::Align2::LEFT_TOP, egui::Align2::RIGHT_TOP, egui::Align2::CENTER_BOTTOM][k];
        painter.text(to_screen(w), anchor, *label, egui::FontId::proportional(11.0), egui::Color32::LIGHT_GRAY);
    }
    if let Some(p) = resp.interact_pointer_pos().filter(|_| resp.dragged() || resp.clicked()) {
        let q = (p - origin) / side;
        tf.centre = to_barycentric([q.x, q.y]);
    }
    ui.add(egui::Slider::new(&mut tf.width, 0.02..=1.0).text("width"));
    ui.add(egui::Slider::new(&mut tf.threshold, 0.0..=1.0).text("threshold"));
    ui.add(egui::Slider::new(&mut tf.opacity, 0.0..=1.0).text("max opacity"));
    ui.horizontal(|ui| {
        ui.checkbox(&mut tf.invert, "invert");
        ui.checkbox(&mut tf.stretch, "stretch");
    });
    ui.horizontal(|ui| {
        ui.radio_value(&mut tf.denominator, WestinDenominator::Trace, "trace");
        ui.radio_value(&mut tf.denominator, WestinDenominator::Largest, "l1");
    });
    ui.horizontal(|ui| {
        for (k, label) in ["linear", "planar", "spherical"].iter().enumerate() {
            let mut c = tf.corners[k].map(|v| v as f32);
            if ui.color_edit_button_rgb(&mut c).changed() {
                tf.corners[k] = c.map(f64::from);
            }
            ui.label(*label);
        }
    });
}

/// Each measure mapped to its data range, as the function's stretch does.
fn stretch(w: [f64; 3], r: &fascicle_core::dti::barycentric::Ranges) -> [f64; 3] {
    std::array::from_fn(|k| {
        let span = r[k].1 - r[k].0;
        if span > 0.0 { ((w[k] - r[k].0) / span).clamp(0.0, 1.0) } else { 0.0 }
    })
}

/// Barycentric coordinates (cl, cp, cs) of a point in widget units, clamped into the triangle.
pub fn to_barycentric(q: [f32; 2]) -> [f64; 3] {
    let [a, b, c] = TRI.map(|v| [v[0] as f64, v[1] as f64]);
    let (px, py) = (q[0] as f64, q[1] as f64);
    let det = (b[1] - c[1]) * (a[0] - c[0]) + (c[0] - b[0]) * (a[1] - c[1]);
    let l0 = ((b[1] - c[1]) * (px - c[0]) + (c[0] - b[0]) * (py - c[1])) / det;
    let l1 = ((c[1] - a[1]) * (px - c[0]) + (a[0] - c[0]) * (py - c[1])) / det;
    let w = [l0, l1, 1.0 - l0 - l1].map(|v| v.max(0.0));
    let t: f64 = w.iter().sum();
    w.map(|v| v / t)
}

/// For tensors fitted to a DWI: the frame its `.bvec` file is read in (a change refits).
fn bvec_convention_field(ui: &mut egui::Ui, source: &mut fascicle_scene::model::TensorSource) {
    use fascicle_core::io::BvecConvention;
    let fascicle_scene::model::TensorSource::Dwi { bvecs, .. } = source else { return };
    ui.horizontal(|ui| {
        ui.label("b-vectors").on_hover_text(
            "FSL: as FSL, MRtrix3 and dcm2niix define them (x negated on images whose affine has a positive \
             determinant). DIPY: the voxel axes as given. They differ only on positive-determinant images.",
        );
        ui.radio_value(bvecs, BvecConvention::Fsl, "FSL");
        ui.radio_value(bvecs, BvecConvention::Dipy, "DIPY");
    });
}

/// Tensor glyphs: slice and size (rebuild), shape (rebuild), knobs and colour (uniform only).
fn tensor_panel(ui: &mut egui::Ui, kind: &mut LayerKind, _: &LayerData) {
    let LayerKind::TensorGlyphs { source, axis, index, spacing, size, min_fa, render, .. } = kind else { return };
    bvec_convention_field(ui, source);
    slice_controls(ui, axis, index);
    ui.add(egui::Slider::new(spacing, 1..=8).text("spacing (voxels)"));
    ui.add(egui::Slider::new(size, 0.1..=3.0).text("size (voxels)"));
    ui.add(egui::Slider::new(min_fa, 0.0..=1.0).text("min FA"));
    let mut superquadric = matches!(render.shape, TensorShape::Superquadric { .. });
    ui.horizontal(|ui| {
        ui.radio_value(&mut superquadric, false, "ellipsoid");
        ui.radio_value(&mut superquadric, true, "superquadric");
    });
    render.shape = match (superquadric, render.shape) {
        (false, _) => TensorShape::Ellipsoid,
        (true, TensorShape::Superquadric { gamma }) => {
            let mut g = gamma;
            ui.add(egui::Slider::new(&mut g, 0.0..=6.0).text("sharpness gamma"));
            TensorShape::Superquadric { gamma: g }
        }
        (true, TensorShape::Ellipsoid) => TensorShape::default(),
    };
    ui.horizontal(|ui| {
        ui.radio_value(&mut render.colour, TensorColour::Direction, "direction");
        ui.radio_value(&mut render.colour, TensorColour::Fa, "FA");
    });
}

fn tractogram_panel(ui: &mut egui::Ui, kind: &mut LayerKind, _: &LayerData) {
    let LayerKind::Tractogram { path } = kind else { return };
    ui.label(format!("{}", path.display()));
}

fn axes_panel(ui: &mut egui::Ui, kind: &mut LayerKind, _: &LayerData) {
    let LayerKind::Axes { length_mm } = kind else { return };
    ui.add(egui::Slider::new(length_mm, 1.0..=200.0).text("length (mm)"));
}

#[cfg(test)]
mod tests {
    use super::*;
    use fascicle_scene::model::VolumeSource;
    use std::sync::Arc;

    #[test]
    fn every_built_in_kind_has_a_panel_and_registration_overrides() {
        let kinds = [
            LayerKind::Slice { source: VolumeSource::PhantomFa, axis: SliceAxis::Z, index: None, window: None },
            LayerKind::Tractogram { path: "x.trk".into() },
            LayerKind::Axes { length_mm: 1.0 },
            fascicle_scene::model::Scene::default_scene().layers[2].kind.clone(),
            fascicle_scene::model::Scene::default_scene().layers[1].kind.clone(),
        ];
        let mut panels = LayerPanels::default();
        for (k, name) in kinds.iter().zip(["slice", "tractogram", "axes", "sh glyphs", "tensor splats"]) {
            assert_eq!(panels.find(k).map(|p| p.name), Some(name));
        }
        panels.register(LayerPanel {
            name: "mine",
            applies: |k| matches!(k, LayerKind::Axes { .. }),
            show: |_, _, _| {},
        });
        assert_eq!(panels.find(&kinds[2]).map(|p| p.name), Some("mine"));
        assert_eq!(panels.find(&kinds[0]).map(|p| p.name), Some("slice"));
    }

    #[test]
    fn panels_edit_their_kind() {
        // Run each panel in a real egui frame with a click-free pass: it must leave an untouched kind as it
        // was (no spurious edits that would respawn the layer every frame).
        let ctx = egui::Context::default();
        let panels = LayerPanels::default();
        let mut kinds = vec![
            LayerKind::Slice { source: VolumeSource::PhantomFa, axis: SliceAxis::Y, index: Some(7), window: None },
            LayerKind::Axes { length_mm: 30.0 },
            fascicle_scene::model::Scene::default_scene().layers[2].kind.clone(),
            fascicle_scene::model::Scene::default_scene().layers[3].kind.clone(),
            fascicle_scene::model::Scene::default_scene().layers[4].kind.clone(),
            LayerKind::Tracts {
                source: fascicle_scene::model::TractSource::File {
                    path: "tracts.trk".into(),
                    tensors: Some(fascicle_scene::model::TensorSource::Nifti {
                        path: "dti_tensor.nii.gz".into(),
                        order: Default::default(),
                    }),
                },
                mode: fascicle_scene::model::TractMode::Lines,
                render: Default::default(),
                rois: vec![],
                masks: vec![],
                ends_only: false,
                deleted: vec![],
                colouring: Default::default(),
            },
        ];
        let before = kinds.clone();
        let data = LayerData { histogram: Arc::new(vec![5, 100, 30, 0]), ..Default::default() };
        let _ = ctx.run_ui(egui::RawInput::default(), |ui| {
            for k in kinds.iter_mut() {
                let p = *panels.find(k).expect("panel");
                (p.show)(ui, k, &data);
            }
        });
        assert_eq!(kinds, before);
    }

    /// The values' histogram: a click on it hides the streamlines below the value under the pointer.
    #[test]
    fn a_click_on_the_value_histogram_sets_the_threshold() {
        let values = ValueHistogram { range: (2.0, 6.0), counts: vec![3; fascicle_scene::jobs::VALUE_BINS] };
        let (mut window, mut min) = ((0.0, 1.0), None);
        let ctx = egui::Context::default();
        let frame = |events: Vec<egui::Event>, window: &mut (f32, f32), min: &mut Option<f32>| {
            let mut rect = egui::Rect::NOTHING;
            let input = egui::RawInput { events, ..Default::default() };
            let _ = ctx.run_ui(input, |ui| rect = value_histogram(ui, &values, "streamlines", window, Some(min)));
            rect
        };
        let rect = frame(vec![], &mut window, &mut min);
        assert_eq!(min, None, "drawing alone edits nothing");
        let at = egui::pos2(rect.left() + 0.25 * rect.width(), rect.center().y);
        let button = |pressed| egui::Event::PointerButton {
            pos: at,
            button: egui::PointerButton::Primary,
            pressed,
            modifiers: Default::default(),
        };
        frame(vec![egui::Event::PointerMoved(at)], &mut window, &mut min);
        frame(vec![button(true)], &mut window, &mut min);
        frame(vec![button(false)], &mut window, &mut min);
        let m = min.expect("a click sets the threshold");
        assert!((m - 3.0).abs() < 1e-4, "a quarter of the way from 2 to 6: {m}");
        assert_eq!(window, (0.0, 1.0));
    }

    #[test]
    fn tensor_field_text_maps_to_a_source() {
        use fascicle_scene::model::TensorSource;
        assert_eq!(tensor_source_from_text("  "), None);
        assert_eq!(tensor_source_from_text("phantom"), Some(TensorSource::Phantom));
        assert_eq!(
            tensor_source_from_text(" out/tensor.nii.gz "),
            Some(TensorSource::Nifti { path: "out/tensor.nii.gz".into(), order: Default::default() })
        );
    }

    #[test]
    fn barycentric_widget_points_map_back_to_their_measures() {
        for w in [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.2, 0.3, 0.5], [0.6, 0.4, 0.0]] {
            let q = (0..3).fold([0.0f32; 2], |q, k| [q[0] + TRI[k][0] * w[k] as f32, q[1] + TRI[k][1] * w[k] as f32]);
            let back = to_barycentric(q);
            assert!((0..3).all(|k| (back[k] - w[k]).abs() < 1e-6), "{w:?} -> {back:?}");
        }
        // Outside the triangle: clamped onto it, still summing to 1.
        let out = to_barycentric([2.0, 2.0]);
        assert!((out.iter().sum::<f64>() - 1.0).abs() < 1e-12 && out.iter().all(|v| *v >= 0.0));
    }

    #[test]
    fn splat_panel_with_barycentric_widget_leaves_an_unedited_kind() {
        let ctx = egui::Context::default();
        let mut kind = fascicle_scene::model::Scene::load(&crate::repo_path("scenes/spiral50.ron")).unwrap().layers[0]
            .kind
            .clone();
        let before = kind.clone();
        let data = LayerData { eigenvalues: Arc::new(vec![[1.0, 0.5, 0.1], [1.0, 1.0, 1.0]]), ..Default::default() };
        let _ = ctx.run_ui(egui::RawInput::default(), |ui| splat_panel(ui, &mut kind, &data));
        assert_eq!(kind, before);
    }
}
