//! The layering written in ARCHITECTURE.md holds: every `crate::` path in a library module
//! points at a module on a lower layer. The table is read from ARCHITECTURE.md itself, so the
//! document and the code cannot drift apart; a new module without a row fails too.

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// `module -> layer` from the rows of ARCHITECTURE.md's "Layers of the library" table
/// (`| 3 | `render` | … |`).
fn layers() -> BTreeMap<String, u32> {
    let text = std::fs::read_to_string(common::repo_root().join("ARCHITECTURE.md")).unwrap();
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
    let src = common::repo_root().join("src");
    rust_files(&src)
        .into_iter()
        .map(|path| (module_path(&src, &path).remove(0), path))
        .filter(|(module, _)| !matches!(module.as_str(), "main" | "lib" | "cli"))
        .collect()
}

/// Every `.rs` file under `dir`, sorted.
fn rust_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
            } else if path.extension().is_some_and(|e| e == "rs") {
                out.push(path);
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

/// A library file's module path: `src/daemon/store.rs` → `daemon::store`,
/// `src/daemon/api/mod.rs` → `daemon::api`.
fn module_path(src: &Path, file: &Path) -> Vec<String> {
    let rel = file.strip_prefix(src).unwrap();
    let mut parts: Vec<String> = rel
        .components()
        .map(|c| c.as_os_str().to_string_lossy().to_string())
        .collect();
    let last = parts.pop().unwrap();
    if last != "mod.rs" {
        parts.push(last.trim_end_matches(".rs").to_string());
    }
    parts
}

/// The module paths (as written, before resolution) a file's code names through `crate::`,
/// `super::` and `self::`, outside comments and before its first `#[cfg(test)]` (a test
/// module's `super` is the file itself), groups expanded: `use super::{a::X, b}` gives
/// `super::a::X` and `super::b`.
fn relative_paths(text: &str) -> Vec<Vec<String>> {
    let code = without_comments(text);
    let code = ["#[cfg(test)]", "#[cfg(all(test"]
        .iter()
        .filter_map(|attr| code.find(attr))
        .min()
        .map_or(code.as_str(), |at| &code[..at]);
    let chars: Vec<char> = code.chars().collect();
    let mut out = Vec::new();
    let mut i = 0;
    while i < chars.len() {
        let starts_word = i == 0
            || !(chars[i - 1].is_alphanumeric() || chars[i - 1] == '_' || chars[i - 1] == ':');
        let rest: String = chars[i..chars.len().min(i + 8)].iter().collect();
        if starts_word
            && ["crate::", "super::", "self::"]
                .iter()
                .any(|p| rest.starts_with(p))
        {
            i = parse_path(&chars, i, Vec::new(), &mut out);
        } else {
            i += 1;
        }
    }
    out
}

/// `text` without `//` line comments and `/* */` block comments (doc comments included).
fn without_comments(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while !rest.is_empty() {
        match (rest.find("//"), rest.find("/*")) {
            (Some(l), b) if b.is_none_or(|b| l < b) => {
                out.push_str(&rest[..l]);
                rest = rest[l..].find('\n').map_or("", |e| &rest[l + e..]);
            }
            (_, Some(b)) => {
                out.push_str(&rest[..b]);
                rest = rest[b..].find("*/").map_or("", |e| &rest[b + e + 2..]);
            }
            _ => {
                out.push_str(rest);
                rest = "";
            }
        }
    }
    out
}

/// Parses one path at `i` (segments joined by `::`, ending in a name, a `*` or a `{…}` group,
/// an `as alias` skipped) with `prefix` before it; pushes every full path to `out` and returns
/// the index after it (always past `i`, so a stray character cannot stall the scan).
fn parse_path(
    chars: &[char],
    mut i: usize,
    mut prefix: Vec<String>,
    out: &mut Vec<Vec<String>>,
) -> usize {
    let skip_space = |mut i: usize| {
        while i < chars.len() && chars[i].is_whitespace() {
            i += 1;
        }
        i
    };
    let ident_end = |mut i: usize| {
        while i < chars.len() && (chars[i].is_alphanumeric() || chars[i] == '_') {
            i += 1;
        }
        i
    };
    let start = i;
    loop {
        i = skip_space(i);
        if i < chars.len() && chars[i] == '{' {
            i += 1;
            loop {
                while i < chars.len() && (chars[i].is_whitespace() || chars[i] == ',') {
                    i += 1;
                }
                if i >= chars.len() || chars[i] == '}' {
                    return i + 1;
                }
                i = parse_path(chars, i, prefix.clone(), out);
            }
        }
        let name_start = i;
        i = ident_end(i);
        if i == name_start {
            // `*`, or something that is no path: what came before is the path.
            if !prefix.is_empty() {
                out.push(prefix);
            }
            return (i + 1).max(start + 1);
        }
        prefix.push(chars[name_start..i].iter().collect());
        if chars.get(i) == Some(&':') && chars.get(i + 1) == Some(&':') {
            i += 2;
            continue;
        }
        out.push(prefix);
        let after = skip_space(i);
        if chars[after..].starts_with(&['a', 's'])
            && after + 2 < chars.len()
            && chars[after + 2].is_whitespace()
        {
            return ident_end(skip_space(after + 2));
        }
        return i;
    }
}

/// A written path resolved against the module `at` and cut to the longest prefix that is a
/// module file under `src`.
fn resolve(src: &Path, at: &[String], written: &[String]) -> Vec<String> {
    let mut path: Vec<String> = Vec::new();
    let mut rest = written;
    match written.first().map(String::as_str) {
        Some("crate") => rest = &written[1..],
        Some("self") => {
            path = at.to_vec();
            rest = &written[1..];
        }
        Some("super") => {
            path = at.to_vec();
            while rest.first().map(String::as_str) == Some("super") {
                path.pop();
                rest = &rest[1..];
            }
        }
        _ => {}
    }
    let is_module = |p: &[String]| {
        let dir = p.iter().fold(src.to_path_buf(), |d, s| d.join(s));
        dir.with_extension("rs").is_file() || dir.join("mod.rs").is_file()
    };
    for seg in rest {
        path.push(seg.clone());
        if !is_module(&path) {
            path.pop();
            break;
        }
    }
    path
}

/// Pairs of sibling modules (children of one folder, a folder counting as one module) that
/// use each other, besides `allowed`, read from the library under `src`.
fn mutual_imports(src: &Path, allowed: &[(&str, &str)]) -> Vec<String> {
    let mut edges = std::collections::BTreeSet::new();
    for file in rust_files(src) {
        let from = module_path(src, &file);
        if matches!(
            from.first().map(String::as_str),
            Some("main" | "lib" | "cli")
        ) {
            continue;
        }
        for written in relative_paths(&std::fs::read_to_string(&file).unwrap()) {
            let to = resolve(src, &from, &written);
            let common = from.iter().zip(&to).take_while(|(a, b)| a == b).count();
            if from.len() > common && to.len() > common {
                edges.insert((from[..=common].join("::"), to[..=common].join("::")));
            }
        }
    }
    edges
        .iter()
        .filter(|(a, b)| a < b && edges.contains(&(b.clone(), a.clone())))
        .filter(|(a, b)| {
            !allowed.iter().any(|(x, y)| {
                (a, b) == (&x.to_string(), &y.to_string())
                    || (a, b) == (&y.to_string(), &x.to_string())
            })
        })
        .map(|(a, b)| format!("{a} and {b} use each other"))
        .collect()
}

/// No two modules use each other, inside folders too: one of them would have to come first
/// for a reader and for a change. The API's routes and its OpenAPI document are tied by
/// utoipa-axum's macros (the routes carry the document, the document is read off the
/// routes), so that pair stays.
#[test]
fn no_two_modules_use_each_other() {
    let problems = mutual_imports(
        &common::repo_root().join("src"),
        &[("daemon::api", "daemon::openapi")],
    );
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// The check itself can fail: two made-up sibling files that use each other, one through
/// `super::` and one through a `crate::` group with a glob, are reported; a parent using its
/// child is not, nor are paths in comments or a test module, nor an alias that happens to
/// be a sibling's name.
#[test]
fn two_modules_that_use_each_other_are_reported() {
    let dir = tempfile::tempdir().unwrap();
    let src = dir.path();
    std::fs::create_dir_all(src.join("x")).unwrap();
    let files = [
        ("x/mod.rs", "pub mod a;\npub mod b;\npub mod c;\nuse self::a::A;\n"),
        (
            "x/a.rs",
            "use super::b::B;\n// use crate::x::c;\n/* crate::x::c */\n#[cfg(test)]\nmod t { use crate::x::c::C; }\n",
        ),
        (
            "x/b.rs",
            "use crate::{x::{a::*, self}};\nuse super::{a::A as c /* z */};\n",
        ),
        ("x/c.rs", "use super::b::B;\nuse super::a::A;\n"),
        ("y.rs", "use crate::x::a::A;\n"),
    ];
    for (name, text) in files {
        std::fs::write(src.join(name), text).unwrap();
    }
    assert_eq!(
        mutual_imports(src, &[]),
        vec!["x::a and x::b use each other"]
    );
    assert!(mutual_imports(src, &[("x::b", "x::a")]).is_empty());
}
