//! Per-layer parameter panels. Each layer kind contributes its own egui controls through [`LayerPanels`]; the
//! viewer's layer list shows, under each layer, the first panel whose `applies` accepts the layer's kind.
//! A glyph plugin's integration registers its panel the same way as the built-in ones below.

use bevy::prelude::*;
use bevy_egui::egui;

use fascicle_core::dti::glyph::TensorShape;
use fascicle_core::sh::glyph::{GlyphPlane, Lobes, Normalise, Sampling};
use fascicle_sh_glyphs::GlyphColour;
use fascicle_tensors::TensorColour;

use crate::scene::{LayerKind, ShSource, SliceAxis};

/// One layer kind's controls: `show` edits the kind in place (an edit re-syncs the layer).
#[derive(Clone, Copy)]
pub struct LayerPanel {
    pub name: &'static str,
    pub applies: fn(&LayerKind) -> bool,
    pub show: fn(&mut egui::Ui, &mut LayerKind),
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

fn slice_panel(ui: &mut egui::Ui, kind: &mut LayerKind) {
    let LayerKind::Slice { axis, index, .. } = kind else { return };
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
fn glyph_panel(ui: &mut egui::Ui, kind: &mut LayerKind) {
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
        let mut slice = LayerKind::Slice { source: crate::scene::VolumeSource::PhantomFa, axis: *axis, index: *index };
        slice_panel(ui, &mut slice);
        if let LayerKind::Slice { axis: a, index: i, .. } = slice {
            (*axis, *index) = (a, i);
        }
        ui.add(egui::Slider::new(spacing, 1..=8).text("spacing (voxels)"));
    }
    ui.add(egui::Slider::new(&mut style.scale, 0.1..=10.0).text("size (mm)"));
    ui.add(egui::Slider::new(&mut style.sharpen, 1.0..=10.0).text("sharpening"));
    ui.horizontal(|ui| {
        ui.radio_value(&mut style.normalise, Normalise::PerGlyph, "per glyph");
        ui.radio_value(&mut style.normalise, Normalise::Global, "global");
    });
    ui.add(egui::Slider::new(&mut render.h, 0.002..=0.2).logarithmic(true).text("step h (rmax)"));
    ui.add(egui::Slider::new(&mut render.refine, 0..=12).text("bisections"));
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
}

/// Tensor splats: slab and size (rebuild), attenuation and opacity (uniform only).
fn splat_panel(ui: &mut egui::Ui, kind: &mut LayerKind) {
    let LayerKind::TensorSplats { axis, index, thickness, size, min_fa, render, .. } = kind else { return };
    let mut slice = LayerKind::Slice { source: crate::scene::VolumeSource::PhantomFa, axis: *axis, index: *index };
    slice_panel(ui, &mut slice);
    if let LayerKind::Slice { axis: a, index: i, .. } = slice {
        (*axis, *index) = (a, i);
    }
    ui.add(egui::Slider::new(thickness, 1..=15).text("slab (slices)"));
    ui.add(egui::Slider::new(size, 0.1..=2.0).text("size (voxels)"));
    ui.add(egui::Slider::new(min_fa, 0.0..=1.0).text("min FA"));
    ui.checkbox(&mut render.attenuation, "depth attenuation");
    ui.add(egui::Slider::new(&mut render.opacity, 0.0..=2.0).text("opacity"));
}

/// Tensor glyphs: slice and size (rebuild), shape (rebuild), knobs and colour (uniform only).
fn tensor_panel(ui: &mut egui::Ui, kind: &mut LayerKind) {
    let LayerKind::TensorGlyphs { axis, index, spacing, size, min_fa, render, .. } = kind else { return };
    let mut slice = LayerKind::Slice { source: crate::scene::VolumeSource::PhantomFa, axis: *axis, index: *index };
    slice_panel(ui, &mut slice);
    if let LayerKind::Slice { axis: a, index: i, .. } = slice {
        (*axis, *index) = (a, i);
    }
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

fn tractogram_panel(ui: &mut egui::Ui, kind: &mut LayerKind) {
    let LayerKind::Tractogram { path } = kind else { return };
    ui.label(format!("{}", path.display()));
}

fn axes_panel(ui: &mut egui::Ui, kind: &mut LayerKind) {
    let LayerKind::Axes { length_mm } = kind else { return };
    ui.add(egui::Slider::new(length_mm, 1.0..=200.0).text("length (mm)"));
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::VolumeSource;

    #[test]
    fn every_built_in_kind_has_a_panel_and_registration_overrides() {
        let kinds = [
            LayerKind::Slice { source: VolumeSource::PhantomFa, axis: SliceAxis::Z, index: None },
            LayerKind::Tractogram { path: "x.trk".into() },
            LayerKind::Axes { length_mm: 1.0 },
            crate::scene::Scene::default_scene().layers[2].kind.clone(),
            crate::scene::Scene::default_scene().layers[1].kind.clone(),
        ];
        let mut panels = LayerPanels::default();
        for (k, name) in kinds.iter().zip(["slice", "tractogram", "axes", "sh glyphs", "tensor splats"]) {
            assert_eq!(panels.find(k).map(|p| p.name), Some(name));
        }
        panels.register(LayerPanel { name: "mine", applies: |k| matches!(k, LayerKind::Axes { .. }), show: |_, _| {} });
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
            LayerKind::Slice { source: VolumeSource::PhantomFa, axis: SliceAxis::Y, index: Some(7) },
            LayerKind::Axes { length_mm: 30.0 },
            crate::scene::Scene::default_scene().layers[2].kind.clone(),
        ];
        let before = kinds.clone();
        let _ = ctx.run_ui(egui::RawInput::default(), |ui| {
            for k in kinds.iter_mut() {
                let p = *panels.find(k).expect("panel");
                (p.show)(ui, k);
            }
        });
        assert_eq!(kinds, before);
    }
}
