//! Robot model: URDF kinematic tree, forward kinematics and visual geometry.
//!
//! FK is owned here (small, exact, nalgebra): revolute, continuous, prismatic, fixed and mimic
//! joints. Visual meshes are loaded once, scaled and placed at their `<origin>` in the link
//! frame, and concatenated into one topology so a posed robot is just a vertex transform.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use nalgebra::{Isometry3, Point3, Translation3, Unit, UnitQuaternion, Vector3};

use crate::error::{Error, Result};
use crate::geometry::from_xyz_rpy;
use crate::mesh::{load_mesh_file, TriMesh};

mod mount;
mod packages;
mod urdf_numbers;
mod xacro;

use packages::resolve_mesh_uri;
pub use packages::{LazyPackages, PackageIndex};

/// The URDF text of `src`'s description: the file, or a `.xacro` file's expansion (its
/// `$(find NAME)` answered from `packages`). Everything that reads the description
/// (kinematics, collision geometry) goes through here.
pub fn description_text(src: &RobotSource, packages: &LazyPackages<'_>) -> Result<String> {
    xacro::urdf_text(&src.urdf, &src.xacro_args, packages)
}

/// Joint type as FK needs it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum JointKind {
    /// Rotation about `axis`, limited.
    Revolute,
    /// Rotation about `axis`, unlimited.
    Continuous,
    /// Translation along `axis`.
    Prismatic,
    /// Rigid.
    Fixed,
}

/// One URDF joint.
#[derive(Clone, Debug)]
pub struct Joint {
    /// URDF name.
    pub name: String,
    /// Motion type.
    pub kind: JointKind,
    /// Parent link index.
    pub parent: usize,
    /// Child link index.
    pub child: usize,
    /// `parent_from_joint` at zero position.
    pub parent_from_joint: Isometry3<f64>,
    /// Unit axis in the joint frame.
    pub axis: Unit<Vector3<f64>>,
    /// Lower position limit (rad or m).
    pub lower: f64,
    /// Upper position limit (rad or m).
    pub upper: f64,
    /// Velocity limit (rad/s or m/s); 0 when the URDF gives none.
    pub velocity: f64,
    /// `(leader joint index, multiplier, offset)` for a mimic joint.
    pub mimic: Option<(usize, f64, f64)>,
}

/// One actuated joint's instantaneous motion (see [`RobotModel::joint_motions`]).
#[derive(Clone, Debug)]
pub struct JointMotion {
    /// Unit axis, base frame.
    pub axis_base: Vector3<f64>,
    /// A point on the axis, base frame.
    pub origin_base: Point3<f64>,
    /// Translation along the axis instead of rotation about it.
    pub prismatic: bool,
    /// Per link index: whether this joint moves it.
    pub moves_link: Vec<bool>,
}

impl JointMotion {
    /// The joint's motion as a left se(3) increment in the camera frame: a link it moves by
    /// `dq` has its points move by `dq * (rho + phi x p)` in the camera frame, exactly as
    /// under a camera increment `(rho, phi)`, so the outline cannot tell the two apart.
    pub fn twist_in_camera(&self, camera_from_base: &Isometry3<f64>) -> crate::geometry::Twist {
        let axis = camera_from_base.rotation * self.axis_base;
        if self.prismatic {
            crate::geometry::Twist::new(axis.x, axis.y, axis.z, 0.0, 0.0, 0.0)
        } else {
            let o = (camera_from_base * self.origin_base).coords;
            let rho = o.cross(&axis);
            crate::geometry::Twist::new(rho.x, rho.y, rho.z, axis.x, axis.y, axis.z)
        }
    }
}

/// Everything needed to build a [`RobotModel`], as a run or cell config states it.
#[derive(Clone, Debug, Default)]
pub struct RobotSource {
    /// URDF file.
    pub urdf: PathBuf,
    /// `package://NAME` roots.
    pub package_dirs: BTreeMap<String, PathBuf>,
    /// Folders searched for packages (a description repository cloned anywhere), after
    /// `package_dirs` and the ROS environment.
    pub package_paths: Vec<PathBuf>,
    /// Frame `camera_from_base` refers to; default the URDF root.
    pub base_link: Option<String>,
    /// Links whose visuals are not rendered.
    pub ignore_links: Vec<String>,
    /// Actuated joints in the order joint vectors use; default: every movable, non-mimic joint.
    pub joints: Option<Vec<String>>,
    /// Arguments of a `.xacro` description (`name:=value`).
    pub xacro_args: BTreeMap<String, String>,
}

/// A loaded robot: kinematics plus merged visual geometry.
#[derive(Debug)]
pub struct RobotModel {
    /// URDF robot name.
    pub name: String,
    /// Link names, index = link id.
    pub links: Vec<String>,
    /// All joints.
    pub joints: Vec<Joint>,
    /// Joints in parent-before-child order.
    order: Vec<usize>,
    /// Base link index (`camera_from_base` refers to it).
    pub base: usize,
    /// Indices (into `joints`) of the actuated joints, in joint-vector order.
    pub actuated: Vec<usize>,
    /// All rendered visuals merged, vertices in their link frames.
    pub visual: Arc<TriMesh>,
    /// For each vertex of `visual`, its link index.
    pub vertex_link: Arc<Vec<u32>>,
    /// Where it was loaded from (collision geometry is read from the same files).
    pub source: RobotSource,
}

/// Loads one `<visual>`/`<collision>` geometry as a mesh in its own frame plus the scale to
/// apply; mesh files are cached by path (robots reuse them across links).
pub(crate) fn element_mesh(
    geometry: &urdf_rs::Geometry,
    field: &str,
    urdf_path: &Path,
    packages: &LazyPackages<'_>,
    cache: &mut HashMap<PathBuf, Arc<TriMesh>>,
) -> Result<(TriMesh, Vector3<f64>)> {
    let urdf_dir = urdf_path.parent().unwrap_or(Path::new("."));
    Ok(match geometry {
        urdf_rs::Geometry::Mesh { filename, scale } => {
            let path = resolve_mesh_uri(filename, urdf_dir, packages)
                .map_err(|m| Error::input(urdf_path, format!("{field} mesh"), m))?;
            let mesh = match cache.get(&path) {
                Some(m) => m.clone(),
                None => {
                    let m = Arc::new(load_mesh_file(&path)?);
                    cache.insert(path.clone(), m.clone());
                    m
                }
            };
            let s = scale
                .map(|s| Vector3::from(s.0))
                .unwrap_or(Vector3::new(1.0, 1.0, 1.0));
            let (lo, hi) = mesh
                .bounds()
                .unwrap_or((Point3::origin(), Point3::origin()));
            let extent = (hi - lo).component_mul(&s.abs()).max();
            if extent > MAX_LINK_EXTENT_M {
                return Err(Error::input(
                    &path,
                    format!("{field} scale"),
                    format!(
                        "mesh spans {extent:.1} m, which looks like millimetres: add scale=\"0.001 0.001 0.001\" to the <mesh> element in {}",
                        urdf_path.display()
                    ),
                ));
            }
            ((*mesh).clone(), s)
        }
        urdf_rs::Geometry::Box { size } => (TriMesh::cuboid(size.0), Vector3::new(1.0, 1.0, 1.0)),
        urdf_rs::Geometry::Cylinder { radius, length } => (
            TriMesh::cylinder(*radius, *length, 32),
            Vector3::new(1.0, 1.0, 1.0),
        ),
        urdf_rs::Geometry::Sphere { radius } => (
            TriMesh::capsule(*radius, 0.0, 16, 32),
            Vector3::new(1.0, 1.0, 1.0),
        ),
        urdf_rs::Geometry::Capsule { radius, length } => (
            TriMesh::capsule(*radius, *length, 16, 32),
            Vector3::new(1.0, 1.0, 1.0),
        ),
    })
}

/// Largest sane robot-part extent; anything bigger is almost surely a unit mistake.
const MAX_LINK_EXTENT_M: f64 = 3.0;

impl RobotModel {
    /// Loads a URDF and its visual meshes.
    pub fn load(src: &RobotSource) -> Result<RobotModel> {
        let urdf_path = &src.urdf;
        let packages = LazyPackages::new(src);
        let text = description_text(src, &packages)?;
        let urdf = urdf_rs::read_from_string(&text)
            .map_err(|e| Error::input(urdf_path, "robot", format!("malformed URDF: {e}")))?;
        urdf_numbers::check(&urdf, urdf_path)?;
        let links: Vec<String> = urdf.links.iter().map(|l| l.name.clone()).collect();
        let link_index: HashMap<&str, usize> = links
            .iter()
            .enumerate()
            .map(|(i, n)| (n.as_str(), i))
            .collect();
        if links.is_empty() {
            return Err(Error::input(urdf_path, "robot", "URDF has no <link>"));
        }
        let mut joints = urdf
            .joints
            .iter()
            .map(|j| convert_joint(j, &link_index, urdf_path))
            .collect::<Result<Vec<_>>>()?;
        let joint_index: HashMap<String, usize> = joints
            .iter()
            .enumerate()
            .map(|(i, j)| (j.name.clone(), i))
            .collect();
        link_mimics(&urdf.joints, &mut joints, &joint_index, urdf_path)?;
        let (root, order) = tree_order(&joints, &links, urdf_path)?;
        let base = match &src.base_link {
            Some(name) => *link_index.get(name.as_str()).ok_or_else(|| {
                Error::input(
                    urdf_path,
                    "robot.base_link",
                    format!("no link named '{name}' in the URDF"),
                )
            })?,
            None => root,
        };
        let actuated = actuated_joints(src, &joints, &joint_index, &order, urdf_path)?;
        for name in &src.ignore_links {
            if !link_index.contains_key(name.as_str()) {
                return Err(Error::input(
                    urdf_path,
                    "robot.ignore_links",
                    format!("no link named '{name}' in the URDF"),
                ));
            }
        }

        let (visual, vertex_link) = merged_visuals(&urdf.links, src, &packages)?;
        Ok(RobotModel {
            name: urdf.name.clone(),
            links,
            joints,
            order,
            base,
            actuated,
            visual: Arc::new(visual),
            vertex_link: Arc::new(vertex_link),
            source: src.clone(),
        })
    }

    /// Loads a URDF with the defaults: root as base, every movable non-mimic joint actuated.
    pub fn from_urdf(urdf: impl Into<PathBuf>) -> Result<RobotModel> {
        RobotModel::load(&RobotSource {
            urdf: urdf.into(),
            ..Default::default()
        })
    }

    /// Names of the actuated joints, in joint-vector order.
    pub fn joint_names(&self) -> Vec<&str> {
        self.actuated
            .iter()
            .map(|&i| self.joints[i].name.as_str())
            .collect()
    }

    /// `(lower, upper)` limits of the actuated joints.
    pub fn joint_limits(&self) -> Vec<(f64, f64)> {
        self.actuated
            .iter()
            .map(|&i| (self.joints[i].lower, self.joints[i].upper))
            .collect()
    }

    /// Index of a link by name.
    pub fn link_index(&self, name: &str) -> Option<usize> {
        self.links.iter().position(|l| l == name)
    }

    /// `base_from_link` for every link at actuated positions `q` (radians / metres).
    /// Joints not actuated stay at zero; mimic joints follow their leader.
    ///
    /// # Panics
    /// If `q.len()` differs from the number of actuated joints (callers validate input first).
    pub fn base_from_links(&self, q: &[f64]) -> Vec<Isometry3<f64>> {
        assert_eq!(q.len(), self.actuated.len(), "joint vector length");
        let mut pos = vec![0.0; self.joints.len()];
        for (k, &ji) in self.actuated.iter().enumerate() {
            pos[ji] = q[k];
        }
        // Leaders first, so a mimic of a mimic reads its leader's final value.
        for _ in 0..self.joints.len() {
            let mut changed = false;
            for (i, j) in self.joints.iter().enumerate() {
                if let Some((leader, mul, off)) = j.mimic {
                    let v = pos[leader] * mul + off;
                    if v != pos[i] {
                        pos[i] = v;
                        changed = true;
                    }
                }
            }
            if !changed {
                break;
            }
        }
        let mut root_from = vec![Isometry3::identity(); self.links.len()];
        for &ji in &self.order {
            let j = &self.joints[ji];
            let motion = match j.kind {
                JointKind::Revolute | JointKind::Continuous => Isometry3::from_parts(
                    Translation3::identity(),
                    UnitQuaternion::from_axis_angle(&j.axis, pos[ji]),
                ),
                JointKind::Prismatic => Isometry3::from_parts(
                    Translation3::from(j.axis.into_inner() * pos[ji]),
                    UnitQuaternion::identity(),
                ),
                JointKind::Fixed => Isometry3::identity(),
            };
            root_from[j.child] = root_from[j.parent] * j.parent_from_joint * motion;
        }
        let base_from_root = root_from[self.base].inverse();
        root_from.iter().map(|p| base_from_root * p).collect()
    }

    /// How each actuated joint moves the links at `q`, in the base frame: what a small error
    /// in a reported joint does to the robot's outline (exploration discounts views whose
    /// outline a joint error could fake).
    pub fn joint_motions(&self, q: &[f64]) -> Vec<JointMotion> {
        let poses = self.base_from_links(q);
        // Parent joint of each link, to walk from a link up to the root.
        let mut parent_joint = vec![usize::MAX; self.links.len()];
        for (i, j) in self.joints.iter().enumerate() {
            parent_joint[j.child] = i;
        }
        self.actuated
            .iter()
            .map(|&ji| {
                let j = &self.joints[ji];
                // The joint frame sits at the child link's origin (URDF), axis in that frame.
                let frame = poses[j.child];
                let moves_link: Vec<bool> = (0..self.links.len())
                    .map(|mut l| {
                        for _ in 0..self.links.len() {
                            let pj = parent_joint[l];
                            if pj == usize::MAX {
                                return false;
                            }
                            if pj == ji {
                                return true;
                            }
                            l = self.joints[pj].parent;
                        }
                        false
                    })
                    .collect();
                let axis_base = frame.rotation * j.axis.into_inner();
                let origin_base = Point3::from(frame.translation.vector);
                let prismatic = j.kind == JointKind::Prismatic;
                if moves_link[self.base] {
                    // A base below the joint (a model rooted at a wrist camera's link): the
                    // joint moves everything else the opposite way relative to it.
                    return JointMotion {
                        axis_base: -axis_base,
                        origin_base,
                        prismatic,
                        moves_link: moves_link.iter().map(|m| !m).collect(),
                    };
                }
                JointMotion {
                    axis_base,
                    origin_base,
                    prismatic,
                    moves_link,
                }
            })
            .collect()
    }

    /// Visual vertices in the base frame at joint positions `q`.
    pub fn posed_vertices(&self, q: &[f64]) -> Vec<Point3<f64>> {
        let poses = self.base_from_links(q);
        self.visual
            .vertices
            .iter()
            .zip(self.vertex_link.iter())
            .map(|(v, &l)| poses[l as usize] * v)
            .collect()
    }
}

/// One URDF joint as FK needs it: link indices, kind, unit axis and limits (continuous and
/// limitless joints get ±2π); mimics are linked afterwards, once every joint has an index.
fn convert_joint(
    j: &urdf_rs::Joint,
    link_index: &HashMap<&str, usize>,
    urdf_path: &Path,
) -> Result<Joint> {
    let parent = *link_index.get(j.parent.link.as_str()).ok_or_else(|| {
        Error::input(
            urdf_path,
            format!("joint '{}' parent", j.name),
            format!("unknown link '{}'", j.parent.link),
        )
    })?;
    let child = *link_index.get(j.child.link.as_str()).ok_or_else(|| {
        Error::input(
            urdf_path,
            format!("joint '{}' child", j.name),
            format!("unknown link '{}'", j.child.link),
        )
    })?;
    let kind = match j.joint_type {
        urdf_rs::JointType::Revolute => JointKind::Revolute,
        urdf_rs::JointType::Continuous => JointKind::Continuous,
        urdf_rs::JointType::Prismatic => JointKind::Prismatic,
        urdf_rs::JointType::Fixed => JointKind::Fixed,
        ref other => {
            return Err(Error::input(
                urdf_path,
                format!("joint '{}' type", j.name),
                format!("{other:?} joints are not supported"),
            ))
        }
    };
    let axis = Vector3::from(j.axis.xyz.0);
    let axis = Unit::try_new(axis, 1e-12).ok_or_else(|| {
        Error::input(
            urdf_path,
            format!("joint '{}' axis", j.name),
            "axis has zero length",
        )
    });
    let axis = match (kind, axis) {
        (JointKind::Fixed, _) => Vector3::x_axis(),
        (_, a) => a?,
    };
    let (mut lower, mut upper) = (j.limit.lower, j.limit.upper);
    if kind == JointKind::Continuous || (lower == 0.0 && upper == 0.0 && kind != JointKind::Fixed) {
        lower = -std::f64::consts::PI * 2.0;
        upper = std::f64::consts::PI * 2.0;
    }
    Ok(Joint {
        name: j.name.clone(),
        kind,
        parent,
        child,
        parent_from_joint: from_xyz_rpy(j.origin.xyz.0, j.origin.rpy.0),
        axis,
        lower,
        upper,
        velocity: j.limit.velocity,
        mimic: None,
    })
}

/// Points each mimic joint at its leader (by index); an unknown leader is an input error.
fn link_mimics(
    urdf_joints: &[urdf_rs::Joint],
    joints: &mut [Joint],
    joint_index: &HashMap<String, usize>,
    urdf_path: &Path,
) -> Result<()> {
    for (i, j) in urdf_joints.iter().enumerate() {
        if let Some(m) = &j.mimic {
            let leader = *joint_index.get(&m.joint).ok_or_else(|| {
                Error::input(
                    urdf_path,
                    format!("joint '{}' mimic", j.name),
                    format!("unknown leader joint '{}'", m.joint),
                )
            })?;
            joints[i].mimic = Some((leader, m.multiplier.unwrap_or(1.0), m.offset.unwrap_or(0.0)));
        }
    }
    Ok(())
}

/// Checks the joints form one tree and returns its root link and the joints in
/// parent-before-child order (what FK walks).
fn tree_order(joints: &[Joint], links: &[String], urdf_path: &Path) -> Result<(usize, Vec<usize>)> {
    // Tree structure: every link has at most one parent joint; exactly one root.
    let mut parent_joint: Vec<Option<usize>> = vec![None; links.len()];
    for (i, j) in joints.iter().enumerate() {
        if parent_joint[j.child].is_some() {
            return Err(Error::input(
                urdf_path,
                format!("link '{}'", links[j.child]),
                "link has two parent joints",
            ));
        }
        parent_joint[j.child] = Some(i);
    }
    let roots: Vec<usize> = (0..links.len())
        .filter(|&l| parent_joint[l].is_none())
        .collect();
    if roots.len() != 1 {
        let names: Vec<&str> = roots.iter().map(|&r| links[r].as_str()).collect();
        return Err(Error::input(
            urdf_path,
            "robot",
            format!("URDF must have exactly one root link, found {names:?}"),
        ));
    }
    let root = roots[0];
    let mut order = Vec::with_capacity(joints.len());
    let mut stack = vec![root];
    while let Some(l) = stack.pop() {
        for (i, j) in joints.iter().enumerate() {
            if j.parent == l {
                order.push(i);
                stack.push(j.child);
            }
        }
    }
    if order.len() != joints.len() {
        return Err(Error::input(urdf_path, "robot", "joint graph has a cycle"));
    }
    Ok((root, order))
}

/// A joint listed twice would be driven by two entries of every joint vector, and the second
/// silently wins: refuse it.
fn check_unique_joints(names: &[String], urdf_path: &Path) -> Result<()> {
    for (k, n) in names.iter().enumerate() {
        if let Some(first) = names[..k].iter().position(|m| m == n) {
            return Err(Error::input(
                urdf_path,
                format!("robot.joints[{k}]"),
                format!("'{n}' is listed twice (also robot.joints[{first}]): list each joint once"),
            ));
        }
    }
    Ok(())
}

/// Actuated joints in joint-vector order: the configured list (validated: known, not mimic,
/// not fixed) or, by default, every movable non-mimic joint in tree order.
fn actuated_joints(
    src: &RobotSource,
    joints: &[Joint],
    joint_index: &HashMap<String, usize>,
    order: &[usize],
    urdf_path: &Path,
) -> Result<Vec<usize>> {
    if let Some(names) = &src.joints {
        check_unique_joints(names, urdf_path)?;
    }
    Ok(match &src.joints {
        Some(names) => names
            .iter()
            .map(|n| {
                let i = *joint_index.get(n).ok_or_else(|| {
                    Error::input(
                        urdf_path,
                        "robot.joints",
                        format!("no joint named '{n}' in the URDF"),
                    )
                })?;
                if joints[i].mimic.is_some() {
                    return Err(Error::input(
                        urdf_path,
                        "robot.joints",
                        format!("joint '{n}' mimics another joint: list its leader instead"),
                    ));
                }
                if joints[i].kind == JointKind::Fixed {
                    return Err(Error::input(
                        urdf_path,
                        "robot.joints",
                        format!("joint '{n}' is fixed and cannot be actuated"),
                    ));
                }
                Ok(i)
            })
            .collect::<Result<Vec<_>>>()?,
        None => order
            .iter()
            .copied()
            .filter(|&i| joints[i].kind != JointKind::Fixed && joints[i].mimic.is_none())
            .collect(),
    })
}

/// Every rendered link's visuals placed in its frame and merged into one mesh, with each
/// vertex's link index (so posing the robot is a per-vertex transform).
fn merged_visuals(
    urdf_links: &[urdf_rs::Link],
    src: &RobotSource,
    packages: &LazyPackages<'_>,
) -> Result<(TriMesh, Vec<u32>)> {
    let urdf_path = &src.urdf;
    let mut cache: HashMap<PathBuf, Arc<TriMesh>> = HashMap::new();
    let mut visual = TriMesh::default();
    let mut vertex_link = Vec::new();
    for (li, link) in urdf_links.iter().enumerate() {
        if src.ignore_links.iter().any(|n| n == &link.name) {
            continue;
        }
        for (vi, v) in link.visual.iter().enumerate() {
            let field = format!("link '{}' visual {vi}", link.name);
            let origin = from_xyz_rpy(v.origin.xyz.0, v.origin.rpy.0);
            let (mesh, scale) = element_mesh(&v.geometry, &field, urdf_path, packages, &mut cache)?;
            let placed = mesh.transformed(scale, &origin);
            vertex_link.extend(std::iter::repeat_n(li as u32, placed.vertices.len()));
            visual.append(&placed);
        }
    }
    Ok((visual, vertex_link))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write_urdf(dir: &Path, body: &str) -> PathBuf {
        let p = dir.join("r.urdf");
        std::fs::write(&p, format!("<robot name=\"t\">{body}</robot>")).unwrap();
        p
    }

    #[test]
    fn mimic_and_prismatic_follow_leader() {
        let d = tempfile::tempdir().unwrap();
        let urdf = write_urdf(
            d.path(),
            r#"<link name="a"/><link name="b"/><link name="c"/>
            <joint name="j1" type="prismatic"><parent link="a"/><child link="b"/><axis xyz="0 1 0"/><limit lower="0" upper="1" effort="1" velocity="1"/></joint>
            <joint name="j2" type="prismatic"><parent link="a"/><child link="c"/><axis xyz="0 -1 0"/><limit lower="0" upper="1" effort="1" velocity="1"/><mimic joint="j1" multiplier="2" offset="0.1"/></joint>"#,
        );
        let m = RobotModel::load(&RobotSource {
            urdf,
            ..Default::default()
        })
        .unwrap();
        assert_eq!(m.joint_names(), vec!["j1"]);
        let poses = m.base_from_links(&[0.2]);
        assert!((poses[1].translation.y - 0.2).abs() < 1e-12);
        assert!((poses[2].translation.y + 0.5).abs() < 1e-12);
    }

    #[test]
    fn unresolvable_package_uri_names_the_fix() {
        let d = tempfile::tempdir().unwrap();
        let urdf = write_urdf(
            d.path(),
            r#"<link name="a"><visual><geometry><mesh filename="package://nowhere_pkg/m.stl"/></geometry></visual></link>"#,
        );
        let e = RobotModel::load(&RobotSource {
            urdf,
            ..Default::default()
        })
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("package_dirs") && e.contains("nowhere_pkg"),
            "{e}"
        );
    }
}
