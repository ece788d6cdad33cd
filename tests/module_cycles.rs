//! No import circles between modules (issue #34): in every crate of the workspace, no module reaches itself
//! through the modules it uses (`use crate::…`, `super::…`, paths written inline), counted between modules
//! of which neither contains the other (a child using its parent's items, or a parent declaring and
//! re-exporting its children, is how Rust modules nest). A name a module re-exports from a child
//! (`pub use child::Name`) counts as the child's. Test modules (`#[cfg(test)] mod …`) are left out.
//!
//! Circles tolerated for a while are listed in `KNOWN` (none now: the app's layer system was the last, broken
//! when the views moved to their own crate): the check fails if one grows, if another appears anywhere, or once
//! a listed one is gone (then remove it from the list).

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::{Path, PathBuf};

type Module = Vec<String>;

/// Circles this check tolerates for now (crate folder, modules): none.
const KNOWN: &[(&str, &[&str])] = &[];

/// Every crate's source folder, relative to the workspace root.
const CRATES: &[&str] = &[
    "core/src",
    "plugins/render/src",
    "plugins/sh_glyphs/src",
    "plugins/tensors/src",
    "plugins/volume/src",
    "plugins/tracts/src",
    "plugins/views/src",
    "plugins/scene/src",
    "src",
    "bench/src",
];

fn root() -> PathBuf {
    PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| env!("CARGO_MANIFEST_DIR").into()))
}

/// The modules of a crate: `lib.rs`/`main.rs` is the root, `a/mod.rs` and `a.rs` are `a`, `a/b.rs` is `a::b`.
fn modules(src: &Path) -> BTreeMap<Module, PathBuf> {
    fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
        for entry in std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())).flatten() {
            let p = entry.path();
            if p.is_dir() {
                walk(&p, out);
            } else if p.extension().is_some_and(|e| e == "rs") {
                out.push(p);
            }
        }
    }
    let mut files = Vec::new();
    walk(src, &mut files);
    files
        .into_iter()
        .map(|p| {
            let rel = p.strip_prefix(src).unwrap().with_extension("");
            let mut m: Module = rel.iter().map(|s| s.to_string_lossy().into_owned()).collect();
            if matches!(m.last().map(String::as_str), Some("lib" | "main" | "mod")) {
                m.pop();
            }
            (m, p)
        })
        .collect()
}

/// The code of a file without comments and without its test modules.
fn code(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while !rest.is_empty() {
        if let Some(r) = rest.strip_prefix("//") {
            rest = r.find('\n').map_or("", |i| &r[i..]);
        } else if let Some(r) = rest.strip_prefix("/*") {
            rest = r.find("*/").map_or("", |i| &r[i + 2..]);
        } else if let Some(r) = rest.strip_prefix('"') {
            // A string literal: skipped (escapes included).
            let mut chars = r.char_indices();
            let mut end = r.len();
            while let Some((i, c)) = chars.next() {
                match c {
                    '\\' => {
                        chars.next();
                    }
                    '"' => {
                        end = i + 1;
                        break;
                    }
                    _ => {}
                }
            }
            out.push_str("\"\"");
            rest = &r[end..];
        } else {
            let c = rest.chars().next().unwrap();
            out.push(c);
            rest = &rest[c.len_utf8()..];
        }
    }
    // Test modules run after the code they test, at the end of a file.
    let mut cut = out.len();
    let mut from = 0;
    while let Some(i) = out[from..].find("#[cfg(test)]") {
        let at = from + i;
        let after = out[at + 12..].trim_start();
        if after.starts_with("mod ") || after.starts_with("pub mod ") {
            cut = at;
            break;
        }
        from = at + 12;
    }
    out.truncate(cut);
    out
}

/// The paths of a `use` tree (`a::{b, c::{d as e}}` is `a::b`, `a::c::d`).
fn use_paths(prefix: &[String], tree: &str, out: &mut Vec<Vec<String>>) {
    let mut parts = Vec::new();
    let (mut depth, mut start) = (0, 0);
    for (i, c) in tree.char_indices() {
        match c {
            '{' => depth += 1,
            '}' => depth -= 1,
            ',' if depth == 0 => {
                parts.push(&tree[start..i]);
                start = i + 1;
            }
            _ => {}
        }
    }
    parts.push(&tree[start..]);
    for part in parts.iter().map(|p| p.trim()).filter(|p| !p.is_empty()) {
        let segs = |s: &str| -> Vec<String> {
            s.split("::").map(str::trim).filter(|s| !s.is_empty()).map(String::from).collect()
        };
        match (part.find('{'), part.rfind('}')) {
            (Some(a), Some(b)) if a < b => {
                let mut p = prefix.to_vec();
                p.extend(segs(&part[..a]));
                use_paths(&p, &part[a + 1..b], out);
            }
            _ => {
                let mut p = prefix.to_vec();
                p.extend(segs(part.split(" as ").next().unwrap_or(part)));
                out.push(p);
            }
        }
    }
}

fn ident_end(s: &str) -> usize {
    s.find(|c: char| !(c.is_alphanumeric() || c == '_')).unwrap_or(s.len())
}

/// The crate-relative paths a module's code names: `use` trees and inline `crate::`/`super::`/`self::` paths.
fn named_paths(module: &Module, code: &str) -> Vec<Module> {
    let mut raw = Vec::new();
    let bytes = code.as_bytes();
    let boundary = |i: usize| i == 0 || !(bytes[i - 1].is_ascii_alphanumeric() || bytes[i - 1] == b'_');
    let mut i = 0;
    while i < code.len() {
        let rest = &code[i..];
        if boundary(i) && rest.starts_with("use ") {
            let end = rest.find(';').unwrap_or(rest.len());
            use_paths(&[], &rest[4..end], &mut raw);
            i += end.max(1);
            continue;
        }
        if boundary(i) && ["crate::", "super::", "self::"].iter().any(|k| rest.starts_with(k)) {
            let mut end = 0;
            loop {
                end += ident_end(&rest[end..]);
                if rest[end..].starts_with("::") && rest[end + 2..].starts_with(|c: char| c.is_alphabetic() || c == '_')
                {
                    end += 2;
                } else {
                    break;
                }
            }
            raw.push(rest[..end].split("::").map(String::from).collect());
            i += end.max(1);
            continue;
        }
        i += rest.chars().next().map_or(1, char::len_utf8);
    }
    raw.into_iter()
        .filter_map(|mut p: Vec<String>| {
            let mut base = module.clone();
            match p.first().map(String::as_str) {
                Some("crate") => {
                    base.clear();
                    p.remove(0);
                }
                Some("self") => {
                    p.remove(0);
                }
                Some("super") => {
                    while p.first().is_some_and(|s| s == "super") {
                        base.pop();
                        p.remove(0);
                    }
                }
                _ => return None,
            }
            base.extend(p);
            Some(base)
        })
        .collect()
}

/// Module edges of one crate, then its circles (strongly connected components of more than one module).
fn circles(src: &Path) -> Vec<BTreeSet<String>> {
    let mods = modules(src);
    let codes: BTreeMap<&Module, String> = mods
        .iter()
        .map(|(m, p)| (m, code(&std::fs::read_to_string(p).unwrap_or_else(|e| panic!("{}: {e}", p.display())))))
        .collect();
    // `pub use child::…::Name` in a module: the name is the child's.
    let mut reexports: HashMap<(Module, String), Module> = HashMap::new();
    for (m, c) in &codes {
        for (at, _) in c.match_indices("pub use ") {
            let tree = &c[at + 8..at + 8 + c[at + 8..].find(';').unwrap_or(0)];
            let mut paths = Vec::new();
            use_paths(&[], tree, &mut paths);
            for p in paths.into_iter().map(|p| if p.first().is_some_and(|s| s == "self") { p[1..].to_vec() } else { p })
            {
                let child: Module = m.iter().cloned().chain(p.first().cloned()).collect();
                if p.len() >= 2 && mods.contains_key(&child) {
                    reexports.insert(((*m).clone(), p[p.len() - 1].clone()), child);
                }
            }
        }
    }
    let resolve = |path: &Module| -> Option<Module> {
        (0..=path.len()).rev().map(|n| path[..n].to_vec()).find(|pre| mods.contains_key(pre)).map(|pre| {
            match path.get(pre.len()) {
                Some(name) => reexports.get(&(pre.clone(), name.clone())).cloned().unwrap_or(pre),
                None => pre,
            }
        })
    };
    let nested = |a: &Module, b: &Module| a.starts_with(b) || b.starts_with(a);
    let edges: BTreeMap<&Module, BTreeSet<Module>> = codes
        .iter()
        .map(|(m, c)| {
            let to = named_paths(m, c).iter().filter_map(resolve).filter(|t| !nested(m, t)).collect();
            (*m, to)
        })
        .collect();
    // Kosaraju: the modules each reaches, intersected with those that reach it.
    let reach = |from: &Module| {
        let mut seen = BTreeSet::from([from.clone()]);
        let mut stack = vec![from.clone()];
        while let Some(m) = stack.pop() {
            for t in edges.get(&m).into_iter().flatten() {
                if seen.insert(t.clone()) {
                    stack.push(t.clone());
                }
            }
        }
        seen
    };
    let reached: BTreeMap<&Module, BTreeSet<Module>> = mods.keys().map(|m| (m, reach(m))).collect();
    let mut out: Vec<BTreeSet<String>> = Vec::new();
    for m in mods.keys() {
        let circle: BTreeSet<String> =
            reached[m].iter().filter(|t| reached[*t].contains(m)).map(|t| t.join("::")).collect();
        if circle.len() > 1 && !out.contains(&circle) {
            out.push(circle);
        }
    }
    out
}

#[test]
fn no_module_imports_itself_through_others() {
    let mut unexpected = Vec::new();
    for krate in CRATES {
        let found = circles(&root().join(krate));
        let known: Vec<BTreeSet<String>> = KNOWN
            .iter()
            .filter(|(k, _)| k == krate)
            .map(|(_, ms)| ms.iter().map(|s| s.to_string()).collect())
            .collect();
        for c in &found {
            if !known.contains(c) {
                unexpected.push(format!("{krate}: {c:?}"));
            }
        }
        for k in &known {
            assert!(found.contains(k), "{krate}: the known circle {k:?} is gone or changed: update KNOWN ({found:?})");
        }
    }
    assert!(
        unexpected.is_empty(),
        "modules that import each other, directly or through others:\n{}",
        unexpected.join("\n")
    );
}

/// The check finds what it is for: two modules that use each other, one through a re-export and a `use` tree,
/// and not a child using its parent.
#[test]
fn the_check_sees_a_circle() {
    let tmp_dir = tempfile::Builder::new().prefix("fascicle-cycles-").tempdir().unwrap();
    let dir = tmp_dir.path().to_path_buf();
    std::fs::create_dir_all(dir.join("io")).unwrap();
    std::fs::write(dir.join("lib.rs"), "mod io; mod sh;\n").unwrap();
    std::fs::write(dir.join("io/mod.rs"), "mod a; mod b; pub use a::{Thing, other::*};\n").unwrap();
    std::fs::write(dir.join("io/a.rs"), "use super::b::{x, y as z};\npub struct Thing;\n").unwrap();
    std::fs::write(dir.join("io/b.rs"), "// crate::sh is only a comment\nfn f() -> super::Thing { todo!() }\n")
        .unwrap();
    std::fs::write(dir.join("sh.rs"), "use crate::io; #[cfg(test)]\nmod tests { use crate::sh; }\n").unwrap();
    let found = circles(&dir);
    let want: BTreeSet<String> = ["io::a", "io::b"].map(String::from).into();
    assert_eq!(found, vec![want]);
}

#[test]
fn every_workspace_crate_is_checked() {
    let manifest = std::fs::read_to_string(root().join("Cargo.toml")).unwrap();
    let members = manifest.lines().find(|l| l.trim_start().starts_with("members")).expect("workspace members");
    let listed: Vec<&str> = members.split('"').skip(1).step_by(2).collect();
    assert!(listed.len() >= 8, "members line not read: {members}");
    for m in listed {
        assert!(CRATES.contains(&format!("{m}/src").as_str()), "{m} is a workspace member the check does not see");
    }
}
