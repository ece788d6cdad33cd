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

// Viridis, piecewise linear through its values at 0, 1/4, 1/2, 3/4 and 1 (#440154, #3b528b, #21918c,
// #5ec962, #fde725), in linear RGB.
fn viridis(v: f32) -> vec3<f32> {
    let stops = array<vec3<f32>, 5>(
        vec3<f32>(0.0578, 0.0, 0.0844),
        vec3<f32>(0.0423, 0.0865, 0.2582),
        vec3<f32>(0.0152, 0.2831, 0.2623),
        vec3<f32>(0.1119, 0.5841, 0.1221),
        vec3<f32>(0.9823, 0.7913, 0.0194),
    );
    let x = clamp(v, 0.0, 1.0) * 4.0;
    let i = min(u32(x), 3u);
    return mix(stops[i], stops[i + 1u], x - f32(i));
}
