//! Every `.wgsl` under `plugins/*/src/shaders/` parses and validates with naga, imports resolved, with no
//! GPU. Libraries (files with `#define_import_path`) are validated on their own and as imports; entry
//! shaders are composed against small stubs of the Bevy modules they import (only the fields they use).

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use naga_oil::compose::{ComposableModuleDescriptor, Composer, NagaModuleDescriptor, ShaderDefValue, ShaderLanguage};

const BEVY_STUBS: [(&str, &str); 5] = [
    (
        "stub/mesh_functions.wgsl",
        "#define_import_path bevy_pbr::mesh_functions
fn get_world_from_local(instance_index: u32) -> mat4x4<f32> { return mat4x4<f32>(); }
fn mesh_position_local_to_world(m: mat4x4<f32>, p: vec4<f32>) -> vec4<f32> { return m * p; }
fn get_tag(instance_index: u32) -> u32 { return instance_index; }",
    ),
    (
        "stub/view_transformations.wgsl",
        "#define_import_path bevy_pbr::view_transformations
fn position_world_to_clip(p: vec3<f32>) -> vec4<f32> { return vec4<f32>(p, 1.0); }",
    ),
    (
        "stub/forward_io.wgsl",
        "#define_import_path bevy_pbr::forward_io
struct VertexOutput {
    @builtin(position) position: vec4<f32>,
    @location(0) world_position: vec4<f32>,
    @location(1) world_normal: vec3<f32>,
};",
    ),
    (
        "stub/mesh_view_bindings.wgsl",
        "#define_import_path bevy_pbr::mesh_view_bindings
struct View {
    clip_from_world: mat4x4<f32>,
    world_from_view: mat4x4<f32>,
    view_from_world: mat4x4<f32>,
    clip_from_view: mat4x4<f32>,
    view_from_clip: mat4x4<f32>,
    world_from_clip: mat4x4<f32>,
    world_position: vec3<f32>,
    viewport: vec4<f32>,
    main_pass_viewport: vec4<f32>,
};
@group(0) @binding(0) var<uniform> view: View;",
    ),
    (
        "stub/view.wgsl",
        "#define_import_path bevy_render::view
struct View {
    clip_from_world: mat4x4<f32>,
    world_from_view: mat4x4<f32>,
    world_position: vec3<f32>,
};",
    ),
];

fn wgsl_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).expect("shaders/").flatten() {
        let p = e.path();
        if p.is_dir() {
            wgsl_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "wgsl") {
            out.push(p);
        }
    }
}

fn validate(module: &naga::Module, name: &str) {
    naga::valid::Validator::new(naga::valid::ValidationFlags::all(), naga::valid::Capabilities::all())
        .validate(module)
        .unwrap_or_else(|e| panic!("{name}: validation failed: {e:?}"));
}

#[test]
fn every_shader_validates_with_imports_resolved() {
    // Each plugin crate owns a `shaders/` folder; a name is `<crate folder>/<path under shaders/>`.
    let plugins =
        PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| env!("CARGO_MANIFEST_DIR").into()))
            .join("..");
    let mut sources: Vec<(String, String)> = Vec::new();
    for krate in ["render", "sh_glyphs", "tensors", "volume", "tracts"] {
        let root = plugins.join(krate).join("src/shaders");
        let mut files = Vec::new();
        wgsl_files(&root, &mut files);
        files.sort();
        assert!(!files.is_empty(), "{krate}: no shaders");
        for p in files {
            let rel = p.strip_prefix(&root).unwrap().display().to_string();
            sources.push((format!("{krate}/{rel}"), std::fs::read_to_string(&p).unwrap()));
        }
    }
    let defs: HashMap<String, ShaderDefValue> = [("MATERIAL_BIND_GROUP".to_string(), ShaderDefValue::UInt(3))].into();
    let mut composer = Composer::default();
    let mut libs: Vec<&(String, String)> = sources.iter().filter(|(_, s)| s.contains("#define_import_path")).collect();
    let stubs: Vec<(String, String)> = BEVY_STUBS.iter().map(|(p, s)| (p.to_string(), s.to_string())).collect();
    let mut pending: Vec<&(String, String)> = stubs.iter().chain(libs.iter().copied()).collect();
    // Add modules in dependency order: retry those whose imports are not yet known.
    while !pending.is_empty() {
        let before = pending.len();
        pending.retain(|(path, src)| {
            composer
                .add_composable_module(ComposableModuleDescriptor {
                    source: src,
                    file_path: path,
                    language: ShaderLanguage::Wgsl,
                    shader_defs: defs.clone(),
                    ..Default::default()
                })
                .is_err()
        });
        assert!(
            pending.len() < before,
            "unresolvable imports in {:?}",
            pending.iter().map(|p| &p.0).collect::<Vec<_>>()
        );
    }
    libs.sort();
    let entries: Vec<_> = sources.iter().filter(|(_, s)| !s.contains("#define_import_path")).collect();
    assert!(!entries.is_empty() && !libs.is_empty());
    // Libraries on their own, then entry shaders (which must have an entry point).
    for (path, src) in libs.iter().copied().chain(entries.iter().copied()) {
        let m = composer
            .make_naga_module(NagaModuleDescriptor {
                source: src,
                file_path: path,
                shader_defs: defs.clone(),
                ..Default::default()
            })
            .unwrap_or_else(|e| panic!("{path}: {}", e.emit_to_string(&composer)));
        if entries.iter().any(|(p, _)| p == path) {
            assert!(!m.entry_points.is_empty(), "{path}: no entry point");
        }
        validate(&m, path);
    }
    // Every shader file is embedded by its crate (`src/shaders.rs` embeds it, as an asset or as a library),
    // so none is forgotten at run time (the workspace's `tests/shader_embedding.rs` checks the same at run time).
    for (name, _) in &sources {
        let (krate, rel) = name.split_once('/').unwrap();
        let listing = std::fs::read_to_string(plugins.join(krate).join("src/shaders.rs")).unwrap();
        let embedded = ["embedded_asset", "load_shader_library"]
            .iter()
            .any(|m| listing.contains(&format!("{m}!(app, \"shaders/{rel}\")")));
        assert!(embedded, "{name} is not embedded by {krate}'s shaders::embed");
    }
}
