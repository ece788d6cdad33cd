//! Every WGSL source of every plugin is registered under its own fixed handle: two plugins sharing a handle
//! would each replace the other's shader (a compute pass would compile a material's shader, or the reverse).

use std::collections::HashMap;

#[test]
fn every_shader_has_its_own_handle() {
    let all = [
        &fascicle_render::shaders::SOURCES[..],
        &fascicle_sh_glyphs::shaders::SOURCES[..],
        &fascicle_tensors::shaders::SOURCES[..],
        &fascicle_tracts::shaders::SOURCES[..],
        &fascicle_volume::shaders::SOURCES[..],
    ];
    let mut seen: HashMap<String, &str> = HashMap::new();
    for (handle, name, _) in all.into_iter().flatten() {
        let id = format!("{:?}", handle.id());
        if let Some(other) = seen.insert(id.clone(), name) {
            panic!("{name} and {other} share the handle {id}");
        }
    }
    assert!(seen.len() >= 13, "{} shaders", seen.len());
}
