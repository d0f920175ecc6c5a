//! Where a ROS package is, as ROS finds it, without a ROS installation: for `package://NAME/…`
//! mesh URIs and for the xacro tool's `$(find NAME)`. The search goes through, in order:
//!
//! 1. `package_dirs`: explicit `NAME = "dir"` roots from the config or run;
//! 2. ROS 2 install prefixes (`AMENT_PREFIX_PATH`: `PREFIX/share/NAME`, registered in the
//!    prefix's ament index or holding a `package.xml` that names it; the first prefix wins, as
//!    overlays do in ROS);
//! 3. ROS 1 source trees (`ROS_PACKAGE_PATH`);
//! 4. `package_paths`: folders to search, such as a description repository cloned anywhere.
//!
//! In a source tree (3 and 4) a package is a folder whose `package.xml` names it; the walk
//! does not descend below a package. A package found in two places of the same step is
//! ambiguous and refused, naming both; one found nowhere is refused, naming where the search
//! looked.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use super::RobotSource;

/// How deep below a source-tree folder a package is looked for.
const SOURCE_TREE_DEPTH: usize = 6;

/// Packages a search lists at most (a whole ROS distribution has under 2,000).
const MAX_PACKAGES: usize = 20_000;

/// Every package a [`RobotSource`] can see, found once and then looked up by name.
#[derive(Debug, Default)]
pub struct PackageIndex {
    found: BTreeMap<String, PathBuf>,
    ambiguous: BTreeMap<String, String>,
    looked_in: String,
}

/// A [`PackageIndex`] built on first use: most descriptions name no package at all.
#[derive(Debug)]
pub struct LazyPackages<'a> {
    src: &'a RobotSource,
    index: OnceLock<PackageIndex>,
}

impl<'a> LazyPackages<'a> {
    /// The packages `src` can see, not yet searched.
    pub fn new(src: &'a RobotSource) -> LazyPackages<'a> {
        LazyPackages {
            src,
            index: OnceLock::new(),
        }
    }

    /// The index, searched now if it was not yet.
    pub fn get(&self) -> &PackageIndex {
        self.index.get_or_init(|| PackageIndex::scan(self.src))
    }
}

impl PackageIndex {
    /// Searches every place `src` and the environment name, in the order of the module docs.
    pub fn scan(src: &RobotSource) -> PackageIndex {
        let env_roots = |var: &str| {
            std::env::var_os(var)
                .map(|v| {
                    std::env::split_paths(&v)
                        .filter(|p| !p.as_os_str().is_empty())
                        .collect::<Vec<_>>()
                })
                .unwrap_or_default()
        };
        let prefixes = env_roots("AMENT_PREFIX_PATH");
        let ros1 = env_roots("ROS_PACKAGE_PATH");
        let mut index = PackageIndex {
            looked_in: looked_in(src, &prefixes, &ros1),
            ..PackageIndex::default()
        };
        for (name, dir) in &src.package_dirs {
            index.found.insert(name.clone(), dir.clone());
        }
        let mut step = Vec::new();
        for prefix in &prefixes {
            installed_packages(prefix, &mut step);
        }
        index.add_first_wins(step);
        // ROS 1 overlays: an earlier root shadows a later one, as roslib finds packages.
        let mut step = Vec::new();
        for root in &ros1 {
            source_packages(root, SOURCE_TREE_DEPTH, &mut step);
        }
        index.add_first_wins(step);
        let mut step = Vec::new();
        for root in &src.package_paths {
            source_packages(root, SOURCE_TREE_DEPTH, &mut step);
        }
        index.add_step(step);
        index
    }

    /// Adds what one step of the search found, the first place of each name winning (ROS 2
    /// overlays: a package in an earlier prefix shadows one in a later prefix).
    fn add_first_wins(&mut self, step: Vec<(String, PathBuf)>) {
        for (name, dir) in step {
            if !self.found.contains_key(&name) && !self.ambiguous.contains_key(&name) {
                self.found.insert(name, dir);
            }
        }
    }

    /// Adds what one source-tree step found; a name found in two folders of the step (and not
    /// settled by an earlier step) is ambiguous.
    fn add_step(&mut self, step: Vec<(String, PathBuf)>) {
        let mut here: BTreeMap<String, PathBuf> = BTreeMap::new();
        for (name, dir) in step {
            if self.found.contains_key(&name) || self.ambiguous.contains_key(&name) {
                continue;
            }
            match here.get(&name) {
                Some(first) if !same_dir(first, &dir) => {
                    let message = format!(
                        "package '{name}' is found twice, in {} and {}; allowed: one of them (name it in robot.package_dirs, or drop a folder from robot.package_paths)",
                        first.display(),
                        dir.display()
                    );
                    here.remove(&name);
                    self.ambiguous.insert(name, message);
                }
                Some(_) => {}
                None => {
                    here.insert(name, dir);
                }
            }
        }
        self.found.extend(here);
    }

    /// Package `name`'s folder, or a one-line reason naming the package and where the search
    /// looked.
    pub fn find(&self, name: &str) -> Result<&Path, String> {
        if let Some(m) = self.ambiguous.get(name) {
            return Err(m.clone());
        }
        self.found.get(name).map(PathBuf::as_path).ok_or_else(|| {
            format!(
                "package '{name}' not found; looked in {}; allowed: a package there, or its folder in robot.package_paths or robot.package_dirs",
                self.looked_in
            )
        })
    }

    /// The table the xacro tool's package lookups answer from (`ament_index_python` stand-in):
    /// `{"found": {name: dir}, "ambiguous": {name: message}, "looked_in": text}`.
    pub fn to_json(&self) -> serde_json::Value {
        // JSON holds UTF-8 text: a package folder whose path is not UTF-8 cannot be handed to
        // xacro, so it is left out (a $(find) of it then says where the search looked).
        let found: BTreeMap<&str, &str> = self
            .found
            .iter()
            .filter_map(|(name, dir)| Some((name.as_str(), dir.to_str()?)))
            .collect();
        serde_json::json!({
            "found": found,
            "ambiguous": self.ambiguous,
            "looked_in": self.looked_in,
        })
    }
}

/// Where a search of `src` looks, as one line for its errors.
fn looked_in(src: &RobotSource, prefixes: &[PathBuf], ros1: &[PathBuf]) -> String {
    let list = |dirs: &[PathBuf]| {
        if dirs.is_empty() {
            "(none)".to_string()
        } else {
            let names: Vec<String> = dirs.iter().map(|d| d.display().to_string()).collect();
            format!("[{}]", names.join(", "))
        }
    };
    let named: Vec<PathBuf> = src.package_dirs.values().cloned().collect();
    format!(
        "robot.package_dirs {}, AMENT_PREFIX_PATH {}, ROS_PACKAGE_PATH {}, robot.package_paths {}",
        list(&named),
        list(prefixes),
        list(ros1),
        list(&src.package_paths)
    )
}

fn same_dir(a: &Path, b: &Path) -> bool {
    a == b || matches!((a.canonicalize(), b.canonicalize()), (Ok(x), Ok(y)) if x == y)
}

/// The file a mesh URI names: `package://`, `file://` or a path relative to `urdf_dir`.
pub(super) fn resolve_mesh_uri(
    uri: &str,
    urdf_dir: &Path,
    packages: &LazyPackages<'_>,
) -> Result<PathBuf, String> {
    if let Some(rest) = uri.strip_prefix("package://") {
        let (pkg, rel) = rest
            .split_once('/')
            .ok_or_else(|| format!("malformed package URI '{uri}'"))?;
        return packages
            .get()
            .find(pkg)
            .map(|dir| dir.join(rel))
            .map_err(|m| format!("cannot resolve '{uri}': {m}"));
    }
    let path = uri.strip_prefix("file://").unwrap_or(uri);
    let p = Path::new(path);
    Ok(if p.is_absolute() {
        p.to_path_buf()
    } else {
        urdf_dir.join(p)
    })
}

/// Every package installed under ROS 2 prefix `prefix`: `PREFIX/share/NAME` folders that the
/// prefix's ament index registers or whose `package.xml` names them.
fn installed_packages(prefix: &Path, out: &mut Vec<(String, PathBuf)>) {
    let share = prefix.join("share");
    let Ok(entries) = std::fs::read_dir(&share) else {
        return;
    };
    let index = share.join("ament_index/resource_index/packages");
    let mut dirs: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir())
        .collect();
    dirs.sort();
    for dir in dirs.into_iter().take(MAX_PACKAGES) {
        let Some(name) = dir.file_name().and_then(|n| n.to_str()).map(str::to_string) else {
            continue;
        };
        if index.join(&name).is_file() || manifest_name(&dir).as_deref() == Some(name.as_str()) {
            out.push((name, dir));
        }
    }
}

/// Every package in a source tree under `dir`: folders whose `package.xml` declares a name;
/// no descent below a package, nor below `depth` levels.
fn source_packages(dir: &Path, depth: usize, out: &mut Vec<(String, PathBuf)>) {
    if out.len() >= MAX_PACKAGES {
        return;
    }
    if dir.join("package.xml").is_file() {
        if let Some(name) = manifest_name(dir) {
            out.push((name, dir.to_path_buf()));
        }
        return;
    }
    // A workspace's build products hold copies of its packages; ignore markers mean "not a
    // package tree", as colcon and catkin read them.
    let skipped = ["COLCON_IGNORE", "CATKIN_IGNORE", "AMENT_IGNORE"]
        .iter()
        .any(|m| dir.join(m).exists())
        || (depth < SOURCE_TREE_DEPTH
            && matches!(
                dir.file_name().and_then(|n| n.to_str()),
                Some("build" | "install" | "log")
            ));
    if depth == 0 || skipped {
        return;
    }
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let mut subs: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir())
        .collect();
    subs.sort();
    for sub in subs {
        source_packages(&sub, depth - 1, out);
    }
}

/// The `<package><name>` a folder's `package.xml` declares; `None` when the manifest is
/// missing, is not XML, or has no name.
fn manifest_name(dir: &Path) -> Option<String> {
    let text = crate::io::read_text_input(&dir.join("package.xml")).ok()?;
    let doc = roxmltree::Document::parse(&text).ok()?;
    let root = doc.root_element();
    if root.tag_name().name() != "package" {
        return None;
    }
    root.children()
        .find(|n| n.has_tag_name("name"))
        .and_then(|n| n.text())
        .map(|t| t.trim().to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn manifest(dir: &Path, body: &str) {
        std::fs::create_dir_all(dir).unwrap();
        std::fs::write(dir.join("package.xml"), body).unwrap();
    }

    #[test]
    fn manifest_name_reads_the_package_element_not_the_first_name_tag() {
        let d = tempfile::tempdir().unwrap();
        manifest(
            d.path(),
            r#"<?xml version="1.0"?>
            <!-- <name>commented_out</name> -->
            <package format="3"><name> real_pkg </name><version>1.0.0</version>
              <maintainer email="a@b.c">A</maintainer></package>"#,
        );
        assert_eq!(manifest_name(d.path()).as_deref(), Some("real_pkg"));
        manifest(d.path(), "<package><name>broken</package>");
        assert_eq!(manifest_name(d.path()), None);
    }

    #[test]
    fn installed_packages_are_found_under_share() {
        let d = tempfile::tempdir().unwrap();
        let share = d.path().join("share");
        manifest(
            &share.join("arm_description"),
            "<package><name>arm_description</name></package>",
        );
        std::fs::create_dir_all(share.join("unregistered")).unwrap();
        let names = |prefix: &Path| {
            let mut found = Vec::new();
            installed_packages(prefix, &mut found);
            found.into_iter().map(|(n, _)| n).collect::<Vec<_>>()
        };
        assert_eq!(names(d.path()), vec!["arm_description".to_string()]);
        let index = share.join("ament_index/resource_index/packages");
        std::fs::create_dir_all(&index).unwrap();
        std::fs::write(index.join("unregistered"), "").unwrap();
        assert_eq!(
            names(d.path()),
            vec!["arm_description".to_string(), "unregistered".to_string()]
        );
    }

    #[test]
    fn a_package_in_two_searched_folders_is_ambiguous_and_a_missing_one_names_the_search() {
        let d = tempfile::tempdir().unwrap();
        for root in ["a", "b"] {
            manifest(
                &d.path().join(root).join("desc"),
                "<package><name>twice_description</name></package>",
            );
        }
        let src = RobotSource {
            package_paths: vec![d.path().join("a"), d.path().join("b")],
            ..RobotSource::default()
        };
        let index = PackageIndex::scan(&src);
        let e = index.find("twice_description").unwrap_err();
        assert!(
            e.contains("found twice") && e.contains("twice_description"),
            "{e}"
        );
        let e = index.find("nowhere_description").unwrap_err();
        assert!(
            e.contains("nowhere_description")
                && e.contains("robot.package_paths")
                && !e.contains('\n'),
            "{e}"
        );
        let pinned = RobotSource {
            package_dirs: [("twice_description".to_string(), d.path().join("a/desc"))].into(),
            ..src
        };
        assert_eq!(
            PackageIndex::scan(&pinned)
                .find("twice_description")
                .unwrap(),
            d.path().join("a/desc")
        );
    }
}
