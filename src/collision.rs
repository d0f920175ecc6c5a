//! Collision geometry: one convex hull per URDF `<collision>` element (a link without
//! collision elements falls back to its visuals), queried with `parry3d`.
//!
//! Hulls are conservative (a hull contains its mesh), which is what a safety check wants;
//! a link made of several elements keeps them apart, so concave links stay tight.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Arc;

use nalgebra::{Isometry3, Point3};
use parry3d_f64::shape::{ConvexPolyhedron, Cuboid, SharedShape};

use crate::error::{Error, Result};
use crate::geometry::from_xyz_rpy;
use crate::mesh::TriMesh;
use crate::robot::{element_mesh, RobotModel};

/// One convex piece of a link, vertices in the link frame.
#[derive(Clone)]
pub struct CollisionElement {
    /// Link index in the robot model.
    pub link: usize,
    /// The hull, in the link frame.
    pub shape: SharedShape,
    /// Centre of the bounding sphere, link frame.
    pub centre: Point3<f64>,
    /// Radius of the bounding sphere, metres (cheap rejection before GJK).
    pub radius_m: f64,
    /// The name of a body the config attached to the link (`[[safety.attached]]`); `None`
    /// for the URDF's own pieces.
    pub attached: Option<String>,
}

impl std::fmt::Debug for CollisionElement {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CollisionElement")
            .field("link", &self.link)
            .field("radius_m", &self.radius_m)
            .field("attached", &self.attached)
            .finish()
    }
}

/// All collision pieces of a robot.
#[derive(Clone, Debug, Default)]
pub struct CollisionModel {
    /// Every piece.
    pub elements: Vec<CollisionElement>,
    /// Piece indices per link.
    pub link_elements: Vec<Vec<usize>>,
}

/// A convex shape around `points` (hull; a thin box around degenerate, flat point sets).
pub fn hull_of(points: &[Point3<f64>]) -> Option<SharedShape> {
    if points.is_empty() {
        return None;
    }
    if let Some(h) = ConvexPolyhedron::from_convex_hull(points) {
        return Some(SharedShape::new(h));
    }
    let mut lo = points[0];
    let mut hi = points[0];
    for p in points {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    let half = ((hi - lo) / 2.0).map(|v| v.max(5e-4));
    let centre = nalgebra::center(&lo, &hi);
    Some(SharedShape::compound(vec![(
        Isometry3::translation(centre.x, centre.y, centre.z),
        SharedShape::new(Cuboid::new(half)),
    )]))
}

/// A ball around `points` (centred on their bounding box; not the smallest, but cheap).
pub fn bounding_sphere(points: &[Point3<f64>]) -> (Point3<f64>, f64) {
    let mut lo = points[0];
    let mut hi = points[0];
    for p in points {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    let c = nalgebra::center(&lo, &hi);
    let r = points.iter().map(|p| (p - c).norm()).fold(0.0, f64::max);
    (c, r)
}

impl CollisionModel {
    /// Reads the collision elements of `robot`'s URDF (the file it was loaded from).
    pub fn load(robot: &RobotModel) -> Result<CollisionModel> {
        let src = &robot.source;
        // The same text the kinematics came from: a xacro description is expanded again.
        let packages = crate::robot::LazyPackages::new(src);
        let text = crate::robot::description_text(src, &packages)?;
        let urdf = urdf_rs::read_from_string(&text)
            .map_err(|e| Error::input(&src.urdf, "robot", format!("malformed URDF: {e}")))?;
        let mut cache: HashMap<PathBuf, Arc<TriMesh>> = HashMap::new();
        let mut model = CollisionModel {
            elements: Vec::new(),
            link_elements: vec![Vec::new(); robot.links.len()],
        };
        for link in &urdf.links {
            let Some(li) = robot.link_index(&link.name) else {
                continue;
            };
            let pieces: Vec<(&urdf_rs::Geometry, &urdf_rs::Pose, String)> =
                if link.collision.is_empty() {
                    link.visual
                        .iter()
                        .enumerate()
                        .map(|(i, v)| {
                            (
                                &v.geometry,
                                &v.origin,
                                format!("link '{}' visual {i}", link.name),
                            )
                        })
                        .collect()
                } else {
                    link.collision
                        .iter()
                        .enumerate()
                        .map(|(i, c)| {
                            (
                                &c.geometry,
                                &c.origin,
                                format!("link '{}' collision {i}", link.name),
                            )
                        })
                        .collect()
                };
            for (geometry, origin, field) in pieces {
                let (mesh, scale) =
                    element_mesh(geometry, &field, &src.urdf, &packages, &mut cache)?;
                let placed = mesh.transformed(scale, &from_xyz_rpy(origin.xyz.0, origin.rpy.0));
                let Some(shape) = hull_of(&placed.vertices) else {
                    continue;
                };
                let (centre, radius_m) = bounding_sphere(&placed.vertices);
                model.link_elements[li].push(model.elements.len());
                model.elements.push(CollisionElement {
                    link: li,
                    shape,
                    centre,
                    radius_m,
                    attached: None,
                });
            }
        }
        Ok(model)
    }

    /// Adds a body fixed to `link`: `shape` in the link frame, bounded by the ball
    /// `(centre, radius_m)` there. It then moves, and is checked, as a piece of that link.
    pub fn attach(
        &mut self,
        link: usize,
        name: &str,
        shape: SharedShape,
        bound: (Point3<f64>, f64),
    ) {
        self.link_elements[link].push(self.elements.len());
        self.elements.push(CollisionElement {
            link,
            shape,
            centre: bound.0,
            radius_m: bound.1,
            attached: Some(name.to_string()),
        });
    }

    /// Largest distance from a link's origin to any of its collision points, per link.
    pub fn link_reach_m(&self) -> Vec<f64> {
        self.link_elements
            .iter()
            .map(|els| {
                els.iter()
                    .map(|&e| {
                        let el = &self.elements[e];
                        el.centre.coords.norm() + el.radius_m
                    })
                    .fold(0.0, f64::max)
            })
            .collect()
    }
}
