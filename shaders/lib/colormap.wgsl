// Colour maps for scalar data.
#define_import_path fascicle::colormap

// A grey ramp clamped to [0, 1].
fn grey(v: f32) -> vec3<f32> {
    return vec3<f32>(clamp(v, 0.0, 1.0));
}

// Directionally encoded colour: |x|, |y|, |z| of a unit direction scaled by a weight (e.g. FA).
fn direction_rgb(dir: vec3<f32>, weight: f32) -> vec3<f32> {
    return abs(dir) * clamp(weight, 0.0, 1.0);
}
