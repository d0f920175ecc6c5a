//! The layering written in ARCHITECTURE.md holds: every `crate::` path in a library module
//! points at a module on a lower layer. The table is read from ARCHITECTURE.md itself, so the
//! document and the code cannot drift apart; a new module without a row fails too.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// `module -> layer` from the rows of ARCHITECTURE.md's "Layers of the library" table
/// (`| 3 | `render` | … |`).
fn layers() -> BTreeMap<String, u32> {
    let text = std::fs::read_to_string(root().join("ARCHITECTURE.md")).unwrap();
    let section = text
        .split("## Layers of the library")
        .nth(1)
        .expect("ARCHITECTURE.md has a 'Layers of the library' section");
    let section = section.split("\n## ").next().unwrap();
    let mut out = BTreeMap::new();
    for line in section.lines() {
        let cells: Vec<&str> = line.split('|').map(str::trim).collect();
        if cells.len() < 4 {
            continue;
        }
        let (Ok(layer), Some(module)) = (
            cells[1].parse::<u32>(),
            cells[2].strip_prefix('`').and_then(|m| m.split('`').next()),
        ) else {
            continue;
        };
        assert!(
            out.insert(module.to_string(), layer).is_none(),
            "{module} has two rows"
        );
    }
    assert!(out.len() > 10, "no layer table found: {out:?}");
    out
}

/// Every library source file with the top-level module it belongs to (`src/cell/sim.rs` →
/// `cell`); the binary (`main.rs`, `cli/`) and `lib.rs` sit above every layer.
fn library_files() -> Vec<(String, PathBuf)> {
    let mut out = Vec::new();
    let mut stack = vec![root().join("src")];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
            } else if path.extension().is_some_and(|e| e == "rs") {
                let rel = path.strip_prefix(root().join("src")).unwrap();
                let top = rel
                    .components()
                    .next()
                    .unwrap()
                    .as_os_str()
                    .to_string_lossy();
                let module = top.trim_end_matches(".rs").to_string();
                if !matches!(module.as_str(), "main" | "lib" | "cli") {
                    out.push((module, path));
                }
            }
        }
    }
    out.sort();
    out
}

/// The top-level modules a file's code names through `crate::`, outside comments: both
/// paths (`crate::solve::solve`) and the first names of groups (`use crate::{mask, solve::X}`).
fn crate_imports(path: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(path).unwrap();
    let code: String = text
        .lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n");
    let ident = |s: &str| -> String {
        s.chars()
            .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
            .collect()
    };
    let mut out = Vec::new();
    let mut rest = code.as_str();
    while let Some(at) = rest.find("crate::") {
        rest = &rest[at + "crate::".len()..];
        let Some(group) = rest.strip_prefix('{') else {
            out.push(ident(rest));
            continue;
        };
        // Names at the group's top level: after its `{` and after each top-level comma.
        let mut depth = 0;
        let mut item_start = true;
        for (i, c) in group.char_indices() {
            match c {
                '{' => depth += 1,
                '}' if depth == 0 => break,
                '}' => depth -= 1,
                ',' if depth == 0 => item_start = true,
                c if item_start && !c.is_whitespace() => {
                    out.push(ident(&group[i..]));
                    item_start = false;
                }
                _ => {}
            }
        }
    }
    out.retain(|n| !n.is_empty());
    out
}

#[test]
fn every_import_points_down_the_layers_of_architecture_md() {
    let layers = layers();
    let mut problems = Vec::new();
    let mut seen = std::collections::BTreeSet::new();
    for (module, path) in library_files() {
        seen.insert(module.clone());
        let Some(&own) = layers.get(&module) else {
            problems.push(format!("{module}: no row in ARCHITECTURE.md's layer table"));
            continue;
        };
        for target in crate_imports(&path) {
            if target == module || matches!(target.as_str(), "Error" | "Result") {
                continue;
            }
            match layers.get(&target) {
                Some(&l) if l < own => {}
                Some(&l) => problems.push(format!(
                    "{}: {module} (layer {own}) uses {target} (layer {l})",
                    path.display()
                )),
                None => problems.push(format!(
                    "{}: uses crate::{target}, which has no row",
                    path.display()
                )),
            }
        }
    }
    for module in layers.keys() {
        if !seen.contains(module) {
            problems.push(format!("ARCHITECTURE.md lists {module}, which src/ lacks"));
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// The check itself can fail: an upward import in a made-up file is caught.
#[test]
fn an_upward_import_is_reported() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("x.rs");
    std::fs::write(
        &file,
        "use crate::{daemon::{Daemon, Store},\n    mask};\n// crate::bench in a comment\nfn f() { crate::solve::solve(); }\n",
    )
    .unwrap();
    assert_eq!(crate_imports(&file), vec!["daemon", "mask", "solve"]);
    let layers = layers();
    assert!(layers["daemon"] > layers["mask"]);
}
