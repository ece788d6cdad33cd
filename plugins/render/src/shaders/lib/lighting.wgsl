// Lighting shared by the glyph shaders: a headlight (light at the eye) with Lambert diffuse, so a
// glyph's shading depends only on its normal and the view ray and can be reproduced exactly on the CPU.
#define_import_path fascicle::lighting

// base * (ambient + (1 - ambient) * max(dot(n, -view_dir), 0))
fn headlight(base: vec3<f32>, n: vec3<f32>, view_dir: vec3<f32>, ambient: f32) -> vec3<f32> {
    let diffuse = max(dot(normalize(n), -view_dir), 0.0);
    return base * (ambient + (1.0 - ambient) * diffuse);
}
