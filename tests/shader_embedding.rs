//! Every WGSL file of every plugin is embedded by that plugin, under its own crate's `embedded://` path and
//! with the bytes of the file on disk (as Bevy's crates embed theirs): a shader added to a folder but not to
//! its crate's `shaders::embed` would be missing at run time, and two crates cannot share a path.

use std::path::{Path, PathBuf};

use bevy::asset::io::embedded::EmbeddedAssetRegistry;
use bevy::prelude::*;

/// A plugin crate's shaders: its folder under `plugins/`, its crate name, its `shaders::FILES` and
/// `shaders::embed`.
type Embedder = (&'static str, &'static str, &'static [&'static str], fn(&mut App));

fn wgsl_under(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())).flatten() {
        let p = e.path();
        if p.is_dir() {
            wgsl_under(&p, out);
        } else if p.extension().is_some_and(|x| x == "wgsl") {
            out.push(p);
        }
    }
}

#[test]
fn every_shader_file_is_embedded_under_its_crate() {
    let root = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| env!("CARGO_MANIFEST_DIR").into()));
    let crates: [Embedder; 5] = [
        ("render", "fascicle_render", &fascicle_render::shaders::FILES, fascicle_render::shaders::embed),
        ("sh_glyphs", "fascicle_sh_glyphs", &fascicle_sh_glyphs::shaders::FILES, fascicle_sh_glyphs::shaders::embed),
        ("tensors", "fascicle_tensors", &fascicle_tensors::shaders::FILES, fascicle_tensors::shaders::embed),
        ("tracts", "fascicle_tracts", &fascicle_tracts::shaders::FILES, fascicle_tracts::shaders::embed),
        ("volume", "fascicle_volume", &fascicle_volume::shaders::FILES, fascicle_volume::shaders::embed),
    ];
    let mut app = App::new();
    app.add_plugins((MinimalPlugins, AssetPlugin::default())).init_asset::<Shader>();
    let mut total = 0;
    for (folder, name, files, embed) in crates {
        let src = root.join("plugins").join(folder).join("src");
        let mut on_disk = Vec::new();
        wgsl_under(&src.join("shaders"), &mut on_disk);
        let mut on_disk: Vec<String> =
            on_disk.iter().map(|p| p.strip_prefix(&src).unwrap().display().to_string()).collect();
        on_disk.sort();
        let mut listed: Vec<String> = files.iter().map(|f| f.to_string()).collect();
        listed.sort();
        assert_eq!(listed, on_disk, "{name}: shaders::FILES against the files under src/shaders/");
        embed(&mut app);
        let registry = app.world().resource::<EmbeddedAssetRegistry>();
        for f in files {
            let data = registry
                .remove_asset(&Path::new(name).join(f))
                .unwrap_or_else(|| panic!("{name}/{f} is not embedded by {name}::shaders::embed"));
            assert_eq!(data.value(), std::fs::read(src.join(f)).unwrap().as_slice(), "{name}/{f}: embedded bytes");
            total += 1;
        }
    }
    assert_eq!(total, 13);
}
