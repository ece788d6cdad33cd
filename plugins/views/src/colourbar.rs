//! Colour bars: one for every layer carrying a [`ColourBar`] (scalar slices in grey over their window, a
//! volume's transfer function over its range, FA/GFA-coloured glyphs and splats and scalar-coloured tracts on
//! viridis), drawn over the 3D view by a pass of its camera ([`crate::BarOverlay`]), in a window and in headless renders alike.
//!
//! A bar is an image made here on the CPU (its label and range written in a 5x7 pixel font, so no text
//! renderer is needed), shown pixel for pixel: the gradient's column `i` of [`BAR_W`] shows the map
//! at `i / (BAR_W - 1)`. Its pixels are written in sRGB as the display shows them, so a bar looks exactly as
//! the layer it explains.

use bevy::asset::RenderAssetUsages;
use bevy::image::{Image, ImageSampler};
use bevy::math::{URect, UVec2};
use bevy::prelude::Component;
use bevy::render::render_resource::{Extent3d, TextureDimension, TextureFormat};
use fascicle_core::dti::splat::viridis;
use fascicle_core::dvr::TransferFunction;

/// A bar's size in pixels.
pub const BAR_W: u32 = 200;
/// A bar's height in pixels: label, gradient and range.
pub const BAR_H: u32 = 48;
/// Rows of the gradient within the bar image.
pub const GRADIENT_ROWS: std::ops::Range<u32> = 17..31;
/// Space between bars and from the view's edges, pixels.
pub const BAR_GAP: u32 = 8;

/// What a layer's values become on screen.
#[derive(Clone, Debug, PartialEq)]
pub enum ColourMap {
    /// Display grey proportional to the value (slices: the window's low end black, high end white).
    Grey,
    /// `fascicle_core::dti::splat::viridis`, as the glyph and tract shaders evaluate it.
    Viridis,
    /// A volume's transfer function (its colour; opacity is not shown).
    Transfer(Box<TransferFunction>),
}

impl ColourMap {
    /// The linear RGB colour the renderer writes for position `t` in [0, 1] of the range.
    pub fn linear(&self, t: f64) -> [f64; 3] {
        let t = if t.is_finite() { t.clamp(0.0, 1.0) } else { 0.0 };
        match self {
            ColourMap::Grey => [srgb_to_linear(t); 3],
            ColourMap::Viridis => viridis(t).to_array(),
            ColourMap::Transfer(tf) => {
                let c = tf.eval_normalised(t);
                [c[0], c[1], c[2]]
            }
        }
    }

    /// The display (sRGB) byte triple of position `t`.
    pub fn display(&self, t: f64) -> [u8; 3] {
        self.linear(t).map(|c| (linear_to_srgb(c.clamp(0.0, 1.0)) * 255.0).round() as u8)
    }
}

/// The colour bar of a layer: its name, its map and the values at its two ends. Put on a layer entity, it is
/// drawn over the 3D view while the entity is not hidden and [`crate::Views::colour_bars`] is on, stacked by
/// [`fascicle_render::layer::LayerOrder`]. Slice layers of one channel get theirs from the plugin (grey over
/// their window); any other layer gets one when the app inserts it.
#[derive(Component, Clone, Debug, PartialEq)]
pub struct ColourBar {
    /// The layer's name, written at the top left.
    pub label: String,
    /// How the layer's values become colours.
    pub map: ColourMap,
    /// The values at the gradient's left and right ends (the map's positions 0 and 1).
    pub range: (f64, f64),
}

/// Where bar `i` (0 at the bottom) lies in a view of `size` pixels: the bottom-right corner, stacked upwards.
/// `None` when it does not fit.
pub fn bar_rect(size: UVec2, i: u32) -> Option<URect> {
    let x1 = size.x.checked_sub(BAR_GAP)?;
    let y1 = size.y.checked_sub(BAR_GAP + i * (BAR_H + BAR_GAP))?;
    let (x0, y0) = (x1.checked_sub(BAR_W)?, y1.checked_sub(BAR_H)?);
    (y0 >= BAR_GAP && x0 >= BAR_GAP).then(|| URect::new(x0, y0, x1, y1))
}

/// The bar as an sRGB image of `BAR_W x BAR_H`: the label (top left), the gradient, the range's two ends
/// (bottom left and right); transparent elsewhere, text white on a dark outline.
pub fn bar_image(bar: &ColourBar) -> Image {
    let (w, h) = (BAR_W as usize, BAR_H as usize);
    let mut px = vec![0u8; w * h * 4];
    // A dark, half-transparent backing behind the text.
    for p in px.chunks_exact_mut(4) {
        p.copy_from_slice(&[0, 0, 0, 96]);
    }
    for x in 0..w {
        let c = bar.map.display(x as f64 / (w - 1) as f64);
        for y in GRADIENT_ROWS {
            let o = (y as usize * w + x) * 4;
            px[o..o + 4].copy_from_slice(&[c[0], c[1], c[2], 255]);
        }
    }
    let mut text = |s: &str, x: usize, y: usize| draw_text(&mut px, w, h, s, x, y);
    text(&bar.label, 2, 1);
    let (lo, hi) = (number(bar.range.0), number(bar.range.1));
    text(&lo, 2, 33);
    text(&hi, w.saturating_sub(2 + text_width(&hi)), 33);
    srgb_image(BAR_W, BAR_H, px)
}

/// A line of text in the bar's font (white on a dark, half-transparent backing), as an sRGB image one font
/// pixel = 2 pixels tall and wide, with a 2-pixel margin.
pub fn text_image(s: &str) -> Image {
    let (w, h) = (text_width(s) + 2, 7 * SCALE + 4);
    let mut px: Vec<u8> = [0u8, 0, 0, 128].repeat(w * h);
    draw_text(&mut px, w, h, s, 2, 2);
    srgb_image(w as u32, h as u32, px)
}

/// An sRGB RGBA8 image of `width x height` pixels, sampled nearest (shown pixel for pixel), for the render
/// world only.
pub fn srgb_image(width: u32, height: u32, px: Vec<u8>) -> Image {
    let mut image = Image::new(
        Extent3d { width, height, depth_or_array_layers: 1 },
        TextureDimension::D2,
        px,
        TextureFormat::Rgba8UnormSrgb,
        RenderAssetUsages::RENDER_WORLD,
    );
    image.sampler = ImageSampler::nearest();
    image
}

/// A value as a bar labels it: up to 4 significant digits, exponent form for very large or small values.
pub fn number(v: f64) -> String {
    if !v.is_finite() {
        return format!("{v}");
    }
    let a = v.abs();
    if a != 0.0 && !(1e-3..1e5).contains(&a) {
        return format!("{v:.2e}");
    }
    let decimals = if a == 0.0 { 0 } else { (3 - a.log10().floor() as i32).clamp(0, 6) as usize };
    let s = format!("{v:.decimals$}");
    if s.contains('.') { s.trim_end_matches('0').trim_end_matches('.').to_string() } else { s }
}

/// Pixels per font pixel.
const SCALE: usize = 2;

fn text_width(s: &str) -> usize {
    s.chars().count() * 6 * SCALE
}

/// Writes `s` with its top-left corner at (x, y), clipped to the image.
fn draw_text(px: &mut [u8], w: usize, h: usize, s: &str, x: usize, y: usize) {
    let mut set = |cx: usize, cy: usize, rgba: [u8; 4]| {
        if cx < w && cy < h {
            let o = (cy * w + cx) * 4;
            px[o..o + 4].copy_from_slice(&rgba);
        }
    };
    for (k, ch) in s.chars().enumerate() {
        let rows = glyph(ch);
        let gx = x + k * 6 * SCALE;
        if gx + 5 * SCALE > w {
            break;
        }
        for (r, bits) in rows.iter().enumerate() {
            for c in 0..5 {
                if bits & (0x10 >> c) != 0 {
                    for (dy, dx) in (0..SCALE).flat_map(|a| (0..SCALE).map(move |b| (a, b))) {
                        set(gx + c * SCALE + dx, y + r * SCALE + dy, [255, 255, 255, 255]);
                    }
                }
            }
        }
    }
}

/// A 5x7 glyph, rows top to bottom, bit 4 the leftmost column. Letters are upper case; unknown characters
/// are blank.
fn glyph(c: char) -> [u8; 7] {
    match c.to_ascii_uppercase() {
        '0' => [0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E],
        '1' => [0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E],
        '2' => [0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F],
        '3' => [0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E],
        '4' => [0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02],
        '5' => [0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E],
        '6' => [0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E],
        '7' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08],
        '8' => [0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E],
        '9' => [0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C],
        '.' => [0x00, 0x00, 0x00, 0x00, 0x00, 0x0C, 0x0C],
        '-' => [0x00, 0x00, 0x00, 0x1F, 0x00, 0x00, 0x00],
        '+' => [0x00, 0x04, 0x04, 0x1F, 0x04, 0x04, 0x00],
        '_' => [0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x1F],
        '(' => [0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02],
        ')' => [0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08],
        '/' => [0x01, 0x01, 0x02, 0x04, 0x08, 0x10, 0x10],
        ':' => [0x00, 0x0C, 0x0C, 0x00, 0x0C, 0x0C, 0x00],
        'A' => [0x0E, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11],
        'B' => [0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E],
        'C' => [0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E],
        'D' => [0x1C, 0x12, 0x11, 0x11, 0x11, 0x12, 0x1C],
        'E' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F],
        'F' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10],
        'G' => [0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F],
        'H' => [0x11, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11],
        'I' => [0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E],
        'J' => [0x07, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C],
        'K' => [0x11, 0x12, 0x14, 0x18, 0x14, 0x12, 0x11],
        'L' => [0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F],
        'M' => [0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11],
        'N' => [0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11],
        'O' => [0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'P' => [0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10],
        'Q' => [0x0E, 0x11, 0x11, 0x11, 0x15, 0x12, 0x0D],
        'R' => [0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11],
        'S' => [0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E],
        'T' => [0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04],
        'U' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'V' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04],
        'W' => [0x11, 0x11, 0x11, 0x15, 0x15, 0x15, 0x0A],
        'X' => [0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11],
        'Y' => [0x11, 0x11, 0x11, 0x0A, 0x04, 0x04, 0x04],
        'Z' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x10, 0x1F],
        _ => [0; 7],
    }
}

fn srgb_to_linear(c: f64) -> f64 {
    if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }
}

fn linear_to_srgb(c: f64) -> f64 {
    if c <= 0.0031308 { c * 12.92 } else { 1.055 * c.powf(1.0 / 2.4) - 0.055 }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grey_is_linear_on_the_display_and_viridis_matches_its_stops() {
        for i in 0..=255u32 {
            let t = f64::from(i) / 255.0;
            assert_eq!(ColourMap::Grey.display(t), [i as u8; 3]);
        }
        // viridis(1) is its last stop (linear (0.9823, 0.7913, 0.0194)), shown in sRGB.
        let top = ColourMap::Viridis.display(1.0);
        assert_eq!(top, [253, 230, 38]);
    }

    #[test]
    fn numbers_are_short_and_exact_enough() {
        assert_eq!(number(0.0), "0");
        assert_eq!(number(1.0), "1");
        assert_eq!(number(0.6), "0.6");
        assert_eq!(number(0.0015), "0.0015");
        assert_eq!(number(1234.0), "1234");
        assert_eq!(number(123.45), "123.5");
        assert_eq!(number(-12.25), "-12.25");
        assert_eq!(number(2.5e-5), "2.50e-5");
        assert_eq!(number(3.0e6), "3.00e6");
    }

    #[test]
    fn bars_stack_from_the_bottom_right_and_drop_what_does_not_fit() {
        let r0 = bar_rect(UVec2::new(640, 480), 0).unwrap();
        assert_eq!((r0.max.x, r0.max.y), (640 - BAR_GAP, 480 - BAR_GAP));
        assert_eq!((r0.width(), r0.height()), (BAR_W, BAR_H));
        let r1 = bar_rect(UVec2::new(640, 480), 1).unwrap();
        assert_eq!(r1.max.y, r0.min.y - BAR_GAP);
        assert!(bar_rect(UVec2::new(640, 480), 8).is_none());
        assert!(bar_rect(UVec2::new(100, 480), 0).is_none());
    }

    #[test]
    fn a_bar_image_holds_its_gradient_and_its_text() {
        let bar = ColourBar { label: "FA".into(), map: ColourMap::Grey, range: (0.0, 0.8) };
        let img = bar_image(&bar);
        let px = img.data.as_ref().unwrap();
        let at = |x: u32, y: u32| {
            let o = ((y * BAR_W + x) * 4) as usize;
            [px[o], px[o + 1], px[o + 2], px[o + 3]]
        };
        for x in [0, 57, 100, BAR_W - 1] {
            let g = (255.0 * f64::from(x) / f64::from(BAR_W - 1)).round() as u8;
            assert_eq!(at(x, GRADIENT_ROWS.start), [g, g, g, 255]);
        }
        // 'F' is a full-height left stroke at scale 2: columns 2-3, rows 1-14.
        assert!((1..15).all(|y| at(2, y) == [255; 4]));
        // The range's high end "0.8" ends near the right edge; a pixel of its '8' is lit.
        let lit = |x0: u32, x1: u32| (x0..x1).any(|x| (33..47).any(|y| at(x, y) == [255; 4]));
        assert!(lit(BAR_W - 14, BAR_W - 2) && lit(2, 14));
    }
}
