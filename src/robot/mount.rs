//! The robot as a camera on one of its links sees it (eye-in-hand).
//!
//! A camera fixed to link `L` has an unknown `camera_from_L`. Re-rooting the model at `L`
//! expresses every link in `L`'s frame, so a view's posed vertices are `L_from_base(q) *
//! base_from_link(q) * p` and the solver, which renders `camera_from_<model base> * p`, solves
//! for `camera_from_L` with no other change: objective, solver, uncertainty and consensus
//! stay the same for both mounts.
//!
//! Links joined to `L` by fixed joints move with the camera. They look the same in every view
//! and usually sit at or behind the lens, where no pinhole silhouette is faithful, so they
//! are not drawn; a wrist camera's masks should leave them out too (docs/mounts.md).

use std::sync::Arc;

use super::{JointKind, RobotModel};
use crate::error::{Error, Result};
use crate::mesh::TriMesh;

impl RobotModel {
    /// Link indices joined to `link` by fixed joints only, `link` included: the bodies that
    /// move with a camera mounted on it.
    pub fn links_fixed_to(&self, link: usize) -> Vec<usize> {
        let mut rigid = vec![link];
        let mut k = 0;
        while k < rigid.len() {
            let at = rigid[k];
            for j in self.joints.iter().filter(|j| j.kind == JointKind::Fixed) {
                let other = if j.parent == at {
                    j.child
                } else if j.child == at {
                    j.parent
                } else {
                    continue;
                };
                if !rigid.contains(&other) {
                    rigid.push(other);
                }
            }
            k += 1;
        }
        rigid
    }

    /// Whether any actuated joint moves `link` relative to the base link: a camera on a link
    /// that never moves is a fixed camera, and calibrating it as one is better posed.
    pub fn link_moves(&self, link: usize) -> bool {
        let q = vec![0.0; self.actuated.len()];
        self.joint_motions(&q).iter().any(|m| m.moves_link[link])
    }

    /// The model as a camera on `link_name` sees it: rooted at that link (so the solved pose
    /// is `camera_from_<link>`), without the links that move with the camera. `field` names
    /// the config or run key for the error when the link is unknown or never moves.
    pub fn seen_from_link(
        &self,
        link_name: &str,
        file: &std::path::Path,
        field: &str,
    ) -> Result<RobotModel> {
        let link = self.link_index(link_name).ok_or_else(|| {
            Error::input(
                file,
                field,
                format!(
                    "no link named '{link_name}' in {}",
                    self.source.urdf.display()
                ),
            )
        })?;
        if !self.link_moves(link) {
            return Err(Error::input(
                file,
                field,
                format!("link '{link_name}' does not move with any actuated joint: a camera on it is a fixed camera (mount = \"fixed\")"),
            ));
        }
        let mut seen = self.without_links_fixed_to(link);
        seen.base = link;
        seen.source.base_link = Some(link_name.to_string());
        Ok(seen)
    }

    /// The same model, base unchanged, without the links that move with a camera on `link`
    /// (what a simulated wrist camera films).
    pub fn without_links_fixed_to(&self, link: usize) -> RobotModel {
        let rigid = self.links_fixed_to(link);
        let mut source = self.source.clone();
        for &l in &rigid {
            if !source.ignore_links.contains(&self.links[l]) {
                source.ignore_links.push(self.links[l].clone());
            }
        }
        let (visual, vertex_link) = self.visual_without(&rigid);
        RobotModel {
            name: self.name.clone(),
            links: self.links.clone(),
            joints: self.joints.clone(),
            order: self.order.clone(),
            base: self.base,
            actuated: self.actuated.clone(),
            visual: Arc::new(visual),
            vertex_link: Arc::new(vertex_link),
            source,
        }
    }

    /// The merged visual mesh without the vertices and triangles of `links`.
    fn visual_without(&self, links: &[usize]) -> (TriMesh, Vec<u32>) {
        let dropped = |v: u32| links.contains(&(self.vertex_link[v as usize] as usize));
        let mut renumber = vec![u32::MAX; self.visual.vertices.len()];
        let mut mesh = TriMesh::default();
        let mut vertex_link = Vec::new();
        for (i, p) in self.visual.vertices.iter().enumerate() {
            if !dropped(i as u32) {
                renumber[i] = mesh.vertices.len() as u32;
                mesh.vertices.push(*p);
                vertex_link.push(self.vertex_link[i]);
            }
        }
        mesh.triangles = self
            .visual
            .triangles
            .iter()
            .filter(|t| t.iter().all(|&v| !dropped(v)))
            .map(|t| t.map(|v| renumber[v as usize]))
            .collect();
        mesh.build_edges();
        (mesh, vertex_link)
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::Point3;

    use super::*;

    fn arm() -> (tempfile::TempDir, RobotModel) {
        let d = tempfile::tempdir().unwrap();
        let urdf = d.path().join("r.urdf");
        let link = |name: &str| {
            format!(
                r#"<link name="{name}"><visual><geometry><box size="0.1 0.1 0.1"/></geometry></visual></link>"#
            )
        };
        let body = format!(
            r#"<robot name="t">{}{}{}{}
            <joint name="j1" type="revolute"><parent link="base"/><child link="upper"/><origin xyz="0 0 0.5"/><axis xyz="0 1 0"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
            <joint name="j2" type="revolute"><parent link="upper"/><child link="wrist"/><origin xyz="0.5 0 0"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
            <joint name="tool" type="fixed"><parent link="wrist"/><child link="tool"/><origin xyz="0.1 0 0"/></joint></robot>"#,
            link("base"),
            link("upper"),
            link("wrist"),
            link("tool")
        );
        std::fs::write(&urdf, body).unwrap();
        let m = RobotModel::from_urdf(urdf).unwrap();
        (d, m)
    }

    #[test]
    fn a_wrist_view_is_the_base_view_moved_by_the_link_pose() {
        let (_d, m) = arm();
        let seen = m
            .seen_from_link("wrist", std::path::Path::new("c.toml"), "camera.mount.link")
            .unwrap();
        // The wrist and the tool move with the camera: only base and upper are drawn.
        let kept: std::collections::BTreeSet<u32> = seen.vertex_link.iter().copied().collect();
        assert_eq!(kept.into_iter().collect::<Vec<_>>(), vec![0, 1]);
        assert_eq!(seen.visual.vertices.len(), m.visual.vertices.len() / 2);
        assert!(seen
            .visual
            .triangles
            .iter()
            .flatten()
            .all(|&v| (v as usize) < seen.visual.vertices.len()));
        let q = [0.4, -0.7];
        let base_from_wrist = m.base_from_links(&q)[2];
        let in_wrist = seen.posed_vertices(&q);
        let in_base: Vec<Point3<f64>> = m
            .posed_vertices(&q)
            .into_iter()
            .zip(m.vertex_link.iter())
            .filter(|(_, &l)| l < 2)
            .map(|(p, _)| p)
            .collect();
        for (w, b) in in_wrist.iter().zip(&in_base) {
            assert!((base_from_wrist * w - b).norm() < 1e-12);
        }
    }

    #[test]
    fn joint_errors_move_the_links_that_are_not_on_the_camera_side() {
        let (_d, m) = arm();
        let seen = m
            .seen_from_link("wrist", std::path::Path::new("c.toml"), "camera.mount.link")
            .unwrap();
        let q = [0.3, 0.2];
        // Seen from the wrist, a joint error moves the links between it and the base.
        let motions = seen.joint_motions(&q);
        assert_eq!(motions[0].moves_link, vec![true, false, false, false]);
        assert_eq!(motions[1].moves_link, vec![true, true, false, false]);
        // A small j2 step moves base vertices exactly as the motion's twist says.
        let dq = 1e-6;
        let before = seen.posed_vertices(&q);
        let after = seen.posed_vertices(&[q[0], q[1] + dq]);
        let m2 = &motions[1];
        for (a, b) in before.iter().zip(&after).take(8) {
            let predicted = m2.axis_base.cross(&(a - m2.origin_base)) * dq;
            assert!(
                ((b - a) - predicted).norm() < 1e-9,
                "{:?} vs {predicted:?}",
                b - a
            );
        }
    }

    #[test]
    fn a_link_that_never_moves_is_refused_with_the_fix() {
        let (_d, m) = arm();
        let e = m
            .seen_from_link("base", std::path::Path::new("c.toml"), "camera.mount.link")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("camera.mount.link") && e.contains("mount = \"fixed\""),
            "{e}"
        );
        let e = m
            .seen_from_link("nope", std::path::Path::new("c.toml"), "camera.mount.link")
            .unwrap_err()
            .to_string();
        assert!(e.contains("no link named 'nope'"), "{e}");
    }
}
