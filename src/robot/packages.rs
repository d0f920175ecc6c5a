//! Where a `package://NAME/...` mesh URI points, as ROS finds packages: an explicit root from
//! the config first, then ROS 2's install prefixes (`AMENT_PREFIX_PATH`: `PREFIX/share/NAME`),
//! then ROS 1's source trees (`ROS_PACKAGE_PATH`: a folder whose `package.xml` names NAME).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// How deep below a `ROS_PACKAGE_PATH` entry a package is looked for.
const SOURCE_TREE_DEPTH: usize = 6;

/// The file a mesh URI names: `package://`, `file://` or a path relative to `urdf_dir`.
pub(super) fn resolve_mesh_uri(
    uri: &str,
    urdf_dir: &Path,
    package_dirs: &BTreeMap<String, PathBuf>,
) -> Result<PathBuf, String> {
    if let Some(rest) = uri.strip_prefix("package://") {
        let (pkg, rel) = rest
            .split_once('/')
            .ok_or_else(|| format!("malformed package URI '{uri}'"))?;
        return find_package(pkg, package_dirs)
            .map(|dir| dir.join(rel))
            .ok_or_else(|| {
                format!(
                    "cannot resolve '{uri}': add \"{pkg}\" to robot.package_dirs, or source a ROS workspace that has it (AMENT_PREFIX_PATH or ROS_PACKAGE_PATH)"
                )
            });
    }
    let path = uri.strip_prefix("file://").unwrap_or(uri);
    let p = Path::new(path);
    Ok(if p.is_absolute() {
        p.to_path_buf()
    } else {
        urdf_dir.join(p)
    })
}

/// Package `name`'s folder: `package_dirs`, then `AMENT_PREFIX_PATH`, then `ROS_PACKAGE_PATH`.
fn find_package(name: &str, package_dirs: &BTreeMap<String, PathBuf>) -> Option<PathBuf> {
    if let Some(dir) = package_dirs.get(name) {
        return Some(dir.clone());
    }
    let roots = |var: &str| {
        std::env::var_os(var)
            .map(|v| std::env::split_paths(&v).collect::<Vec<_>>())
            .unwrap_or_default()
    };
    roots("AMENT_PREFIX_PATH")
        .iter()
        .find_map(|prefix| installed_package(prefix, name))
        .or_else(|| {
            roots("ROS_PACKAGE_PATH")
                .iter()
                .find_map(|root| source_package(root, name, SOURCE_TREE_DEPTH))
        })
}

/// An installed ROS 2 package: `PREFIX/share/NAME`, registered in the prefix's ament index
/// or holding its manifest.
fn installed_package(prefix: &Path, name: &str) -> Option<PathBuf> {
    let share = prefix.join("share");
    let registered = share
        .join("ament_index/resource_index/packages")
        .join(name)
        .is_file();
    let dir = share.join(name);
    (dir.is_dir() && (registered || manifest_name(&dir).as_deref() == Some(name))).then_some(dir)
}

/// A package in a source tree under `dir`: a folder whose `package.xml` declares `name` (or,
/// lacking a manifest, a folder of that name); no descent below a package.
fn source_package(dir: &Path, name: &str, depth: usize) -> Option<PathBuf> {
    if dir.join("package.xml").is_file() {
        return (manifest_name(dir).as_deref() == Some(name)).then(|| dir.to_path_buf());
    }
    if dir.file_name().and_then(|n| n.to_str()) == Some(name) && dir.is_dir() {
        return Some(dir.to_path_buf());
    }
    if depth == 0 {
        return None;
    }
    let mut entries: Vec<PathBuf> = std::fs::read_dir(dir)
        .ok()?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir())
        .collect();
    entries.sort();
    entries
        .into_iter()
        .find_map(|sub| source_package(&sub, name, depth - 1))
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
        assert_eq!(
            installed_package(d.path(), "arm_description"),
            Some(share.join("arm_description"))
        );
        assert_eq!(installed_package(d.path(), "unregistered"), None);
        let index = share.join("ament_index/resource_index/packages");
        std::fs::create_dir_all(&index).unwrap();
        std::fs::write(index.join("unregistered"), "").unwrap();
        assert_eq!(
            installed_package(d.path(), "unregistered"),
            Some(share.join("unregistered"))
        );
    }
}
