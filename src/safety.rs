//! Motion safety: the one checker every arm target passes through.
//!
//! A move is allowed only if the target is inside the joint limits (the URDF's, the
//! controller's and the cell's configured sub-ranges, intersected), the speed is within the
//! caps, and every pose along the joint-space line from the arm's current pose to the target
//! keeps `margin_m` of clearance between non-adjacent links and to the environment, with every
//! link inside the workspace. The line is sampled so that no collision point moves more than
//! `margin_m / 2` between samples (a bound from each joint's reach), so a thin obstacle cannot
//! fall between two samples: clearance ≥ margin at the samples implies contact-free motion.
//!
//! [`CheckedMove`] can only be built by [`SafetyChecker::check_move`], and [`SafeArm`] only
//! sends `CheckedMove`s, so the type system keeps unchecked targets away from the arm.

use std::path::Path;
use std::sync::Arc;

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use parry3d_f64::bounding_volume::Aabb;
use parry3d_f64::query::{self, PointQuery};
use parry3d_f64::shape::{Ball, Cuboid, HalfSpace, SharedShape};
use rand::{Rng, SeedableRng};

use crate::collision::{hull_of, CollisionModel};
use crate::config::{ObstacleConfig, SafetyConfig};
use crate::error::{Error, Result};
use crate::mesh::load_mesh_file;
use crate::robot::{JointKind, RobotModel};

/// Why a pose or move is refused.
#[derive(Clone, Debug, PartialEq)]
pub enum Violation {
    /// Wrong length or a non-finite value.
    Malformed(String),
    /// A joint outside its allowed range.
    JointLimit {
        /// Joint name.
        joint: String,
        /// Requested value.
        value: f64,
        /// Allowed range.
        range: (f64, f64),
    },
    /// Commanded speed above a cap.
    Speed {
        /// Requested, rad/s.
        requested: f64,
        /// Cap, rad/s.
        cap: f64,
    },
    /// Two links closer than the margin.
    SelfCollision {
        /// Link names.
        links: (String, String),
        /// Clearance, metres.
        clearance_m: f64,
    },
    /// A link closer than the margin to an obstacle (or inside a keep-out zone).
    Environment {
        /// Link name.
        link: String,
        /// Obstacle label.
        obstacle: String,
        /// Clearance, metres.
        clearance_m: f64,
    },
    /// A link outside the workspace ball.
    Workspace {
        /// Link name.
        link: String,
        /// Distance of its piece from the centre, metres.
        distance_m: f64,
    },
    /// A pose along the path violates something.
    Path {
        /// Where along the line, 0..1.
        at_fraction: f64,
        /// What.
        inner: Box<Violation>,
    },
}

impl std::fmt::Display for Violation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Violation::Malformed(m) => write!(f, "malformed target: {m}"),
            Violation::JointLimit {
                joint,
                value,
                range,
            } => write!(
                f,
                "joint {joint} at {value:.4} outside [{:.4}, {:.4}]",
                range.0, range.1
            ),
            Violation::Speed { requested, cap } => {
                write!(f, "speed {requested:.3} rad/s above the cap {cap:.3}")
            }
            Violation::SelfCollision { links, clearance_m } => write!(
                f,
                "links {} and {} within {:.1} mm",
                links.0,
                links.1,
                clearance_m * 1e3
            ),
            Violation::Environment {
                link,
                obstacle,
                clearance_m,
            } => write!(
                f,
                "link {link} within {:.1} mm of {obstacle}",
                clearance_m * 1e3
            ),
            Violation::Workspace { link, distance_m } => write!(
                f,
                "link {link} {:.3} m from the workspace centre",
                distance_m
            ),
            Violation::Path { at_fraction, inner } => {
                write!(f, "{inner} at {:.0}% of the path", at_fraction * 100.0)
            }
        }
    }
}

/// Clearances of an accepted pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Clearance {
    /// Smallest distance between checked link pairs, metres (infinite when none).
    pub self_m: f64,
    /// Smallest distance to the environment, metres (infinite when none).
    pub environment_m: f64,
}

/// A move that passed every check; only [`SafetyChecker::check_move`] makes one.
#[derive(Clone, Debug, PartialEq)]
pub struct CheckedMove {
    from: Vec<f64>,
    to: Vec<f64>,
    speed_rad_s: f64,
    /// Poses checked along the line.
    pub samples: usize,
    /// Smallest clearances along the line.
    pub clearance: Clearance,
}

impl CheckedMove {
    /// Start pose the check assumed.
    pub fn from(&self) -> &[f64] {
        &self.from
    }
    /// Target.
    pub fn to(&self) -> &[f64] {
        &self.to
    }
    /// Speed of the fastest joint, rad/s.
    pub fn speed_rad_s(&self) -> f64 {
        self.speed_rad_s
    }
}

struct EnvShape {
    name: String,
    pose: Isometry3<f64>,
    shape: SharedShape,
    aabb: Option<Aabb>,
}

/// The checker (see the module docs).
pub struct SafetyChecker {
    robot: Arc<RobotModel>,
    collision: CollisionModel,
    names: Vec<String>,
    limits: Vec<(f64, f64)>,
    velocity_caps: Vec<f64>,
    speed_cap: f64,
    margin_m: f64,
    pairs: Vec<(usize, usize)>,
    env: Vec<EnvShape>,
    env_exempt_link: Vec<bool>,
    workspace: Option<(Point3<f64>, f64)>,
    joint_reach_m: Vec<f64>,
    /// Link pairs never checked, with the reason (for `--dry-run` and logs).
    pub skipped_pairs: Vec<(String, String, &'static str)>,
    /// `[safety].min_in_image`.
    pub min_in_image: f64,
}

fn pose_from(xyz: [f64; 3], rpy_deg: [f64; 3]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(xyz[0], xyz[1], xyz[2]),
        UnitQuaternion::from_euler_angles(
            rpy_deg[0].to_radians(),
            rpy_deg[1].to_radians(),
            rpy_deg[2].to_radians(),
        ),
    )
}

/// Link pairs listed as `<disable_collisions link1=… link2=…/>` in a MoveIt SRDF.
pub fn read_srdf_disabled_pairs(path: &Path) -> Result<Vec<(String, String)>> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| Error::io(path, format!("cannot read SRDF: {e}")))?;
    let doc = roxmltree::Document::parse(&text)
        .map_err(|e| Error::input(path, "srdf", format!("malformed XML: {e}")))?;
    Ok(doc
        .descendants()
        .filter(|n| n.has_tag_name("disable_collisions"))
        .filter_map(|n| Some((n.attribute("link1")?.into(), n.attribute("link2")?.into())))
        .collect())
}

impl SafetyChecker {
    /// Builds the checker for `robot` with the controller's `controller_limits` (lower,
    /// upper, max velocity per actuated joint); `config_dir` resolves relative paths.
    pub fn new(
        robot: Arc<RobotModel>,
        cfg: &SafetyConfig,
        controller_limits: &[(f64, f64, f64)],
        config_path: &Path,
    ) -> Result<SafetyChecker> {
        let config_dir = config_path.parent().unwrap_or(Path::new("."));
        let field = |f: &str| format!("safety.{f}");
        if !(cfg.margin_m > 0.0 && cfg.margin_m < 0.5) {
            return Err(Error::input(
                config_path,
                field("margin_m"),
                "must be between 0 and 0.5 m",
            ));
        }
        if !(cfg.speed_cap_rad_s > 0.0 && cfg.speed_cap_rad_s.is_finite()) {
            return Err(Error::input(
                config_path,
                field("speed_cap_rad_s"),
                "must be a positive speed",
            ));
        }
        let collision = CollisionModel::load(&robot)?;
        let names: Vec<String> = robot.joint_names().iter().map(|s| s.to_string()).collect();
        if controller_limits.len() != names.len() {
            return Err(Error::input(
                config_path,
                "arm",
                format!(
                    "the arm reports {} joints but the URDF actuates {}: check robot.joints",
                    controller_limits.len(),
                    names.len()
                ),
            ));
        }
        let urdf_limits = robot.joint_limits();
        let mut limits = Vec::new();
        let mut velocity_caps = Vec::new();
        for (k, name) in names.iter().enumerate() {
            let (ul, uu) = urdf_limits[k];
            let (cl, cu, cv) = controller_limits[k];
            let (mut lo, mut hi) = (ul.max(cl), uu.min(cu));
            if let Some([rl, ru]) = cfg.joint_ranges.get(name) {
                lo = lo.max(*rl);
                hi = hi.min(*ru);
            }
            if lo > hi {
                return Err(Error::input(
                    config_path,
                    field(&format!("joint_ranges.{name}")),
                    format!("empty range after intersecting with the URDF and controller limits [{ul}, {uu}]"),
                ));
            }
            limits.push((lo, hi));
            let urdf_v = robot.joints[robot.actuated[k]].velocity;
            let mut cap = cv.min(cfg.speed_cap_rad_s);
            if urdf_v > 0.0 {
                cap = cap.min(urdf_v);
            }
            velocity_caps.push(cap);
        }
        for name in cfg.joint_ranges.keys() {
            if !names.contains(name) {
                return Err(Error::input(
                    config_path,
                    field("joint_ranges"),
                    format!(
                        "no actuated joint named '{name}' (joints: {})",
                        names.join(", ")
                    ),
                ));
            }
        }

        // Rigid groups: links joined by fixed joints move together.
        let n_links = robot.links.len();
        let mut group: Vec<usize> = (0..n_links).collect();
        fn find(g: &mut [usize], mut i: usize) -> usize {
            while g[i] != i {
                g[i] = g[g[i]];
                i = g[i];
            }
            i
        }
        for j in &robot.joints {
            if j.kind == JointKind::Fixed {
                let (a, b) = (find(&mut group, j.parent), find(&mut group, j.child));
                group[a] = b;
            }
        }
        let groups: Vec<usize> = (0..n_links).map(|l| find(&mut group, l)).collect();
        let mut skip = vec![vec![None::<&'static str>; n_links]; n_links];
        let mut mark = |a: usize, b: usize, why: &'static str| {
            if skip[a][b].is_none() {
                skip[a][b] = Some(why);
                skip[b][a] = Some(why);
            }
        };
        for a in 0..n_links {
            for b in 0..n_links {
                if a != b && groups[a] == groups[b] {
                    mark(a, b, "rigidly attached");
                }
            }
        }
        for j in &robot.joints {
            for a in 0..n_links {
                for b in 0..n_links {
                    if groups[a] == groups[j.parent] && groups[b] == groups[j.child] {
                        mark(a, b, "adjacent");
                    }
                }
            }
        }
        let link = |name: &str, what: &str| {
            robot.link_index(name).ok_or_else(|| {
                Error::input(
                    config_path,
                    field(what),
                    format!("no link named '{name}' in the URDF"),
                )
            })
        };
        for [a, b] in &cfg.allowed_collisions {
            mark(
                link(a, "allowed_collisions")?,
                link(b, "allowed_collisions")?,
                "allowed in config",
            );
        }
        if let Some(srdf) = &cfg.srdf {
            let path = config_dir.join(srdf);
            for (a, b) in read_srdf_disabled_pairs(&path)? {
                // SRDFs often name links of other groups (grippers); ignore unknown names.
                if let (Some(a), Some(b)) = (robot.link_index(&a), robot.link_index(&b)) {
                    mark(a, b, "disabled in SRDF");
                }
            }
        }

        // Environment.
        let mut env = Vec::new();
        for (i, o) in cfg.obstacles.iter().enumerate() {
            let label = |name: &String, kind: &str| {
                if name.is_empty() {
                    format!("{kind} obstacle {i}")
                } else {
                    name.clone()
                }
            };
            let bad = |m: &str| Error::input(config_path, format!("safety.obstacles[{i}]"), m);
            let (name, pose, shape) = match o {
                ObstacleConfig::Plane {
                    name,
                    normal,
                    offset_m,
                } => {
                    let n = Vector3::from(*normal);
                    let n = nalgebra::Unit::try_new(n, 1e-9)
                        .ok_or_else(|| bad("plane normal has zero length"))?;
                    (
                        label(name, "plane"),
                        Isometry3::translation(0.0, 0.0, 0.0)
                            * Translation3::from(n.into_inner() * *offset_m),
                        SharedShape::new(HalfSpace::new(n)),
                    )
                }
                ObstacleConfig::Box {
                    name,
                    centre,
                    size,
                    rpy_deg,
                } => {
                    if size.iter().any(|s| s.is_nan() || *s <= 0.0) {
                        return Err(bad("box size must be positive"));
                    }
                    (
                        label(name, "box"),
                        pose_from(*centre, *rpy_deg),
                        SharedShape::new(Cuboid::new(Vector3::from(*size) / 2.0)),
                    )
                }
                ObstacleConfig::Sphere {
                    name,
                    centre,
                    radius_m,
                } => {
                    if radius_m.is_nan() || *radius_m <= 0.0 {
                        return Err(bad("sphere radius must be positive"));
                    }
                    (
                        label(name, "sphere"),
                        pose_from(*centre, [0.0; 3]),
                        SharedShape::new(Ball::new(*radius_m)),
                    )
                }
                ObstacleConfig::Mesh {
                    name,
                    file,
                    xyz,
                    rpy_deg,
                    scale,
                } => {
                    let mesh = load_mesh_file(&config_dir.join(file))?;
                    let pts: Vec<Point3<f64>> = mesh
                        .vertices
                        .iter()
                        .map(|p| Point3::from(p.coords.component_mul(&Vector3::from(*scale))))
                        .collect();
                    let shape = hull_of(&pts).ok_or_else(|| bad("mesh has no vertices"))?;
                    (label(name, "mesh"), pose_from(*xyz, *rpy_deg), shape)
                }
                ObstacleConfig::KeepOut { name, min, max } => {
                    let (lo, hi) = (Vector3::from(*min), Vector3::from(*max));
                    if (0..3).any(|k| hi[k] <= lo[k]) {
                        return Err(bad("keep-out zone needs min < max on every axis"));
                    }
                    let c = (lo + hi) / 2.0;
                    (
                        label(name, "keep-out zone"),
                        Isometry3::translation(c.x, c.y, c.z),
                        SharedShape::new(Cuboid::new((hi - lo) / 2.0)),
                    )
                }
            };
            let aabb = if matches!(o, ObstacleConfig::Plane { .. }) {
                None
            } else {
                Some(shape.compute_aabb(&pose))
            };
            env.push(EnvShape {
                name,
                pose,
                shape,
                aabb,
            });
        }
        // The base's rigid group cannot be moved by a command: it is exempt from environment
        // checks (it stands on the table by design).
        let base_group = groups[robot.base];
        let env_exempt_link: Vec<bool> = (0..n_links).map(|l| groups[l] == base_group).collect();

        let workspace = match &cfg.workspace {
            Some(w) => {
                if w.radius_m.is_nan() || w.radius_m <= 0.0 {
                    return Err(Error::input(
                        config_path,
                        field("workspace.radius_m"),
                        "must be positive",
                    ));
                }
                Some((Point3::from(w.centre), w.radius_m))
            }
            None => None,
        };

        let joint_reach_m = joint_reach(&robot, &collision);
        let mut checker = SafetyChecker {
            robot: robot.clone(),
            collision,
            names,
            limits,
            velocity_caps,
            speed_cap: cfg.speed_cap_rad_s,
            margin_m: cfg.margin_m,
            pairs: Vec::new(),
            env,
            env_exempt_link,
            workspace,
            joint_reach_m,
            skipped_pairs: Vec::new(),
            min_in_image: cfg.min_in_image,
        };
        // "Always in collision" pairs (MoveIt's setup-assistant rule): in contact in nearly
        // every random pose, so the geometry overlaps by construction (simplified shapes).
        let mut candidates = Vec::new();
        #[allow(clippy::needless_range_loop)] // a symmetric pair table, indexed both ways
        for a in 0..n_links {
            for b in a + 1..n_links {
                let has = |l: usize| !checker.collision.link_elements[l].is_empty();
                if !has(a) || !has(b) {
                    continue;
                }
                match skip[a][b] {
                    Some(why) => checker.skipped_pairs.push((
                        robot.links[a].clone(),
                        robot.links[b].clone(),
                        why,
                    )),
                    None => candidates.push((a, b)),
                }
            }
        }
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let samples: Vec<Vec<f64>> = (0..100)
            .map(|_| {
                checker
                    .limits
                    .iter()
                    .map(|&(lo, hi)| rng.random_range(lo..=hi))
                    .collect()
            })
            .collect();
        for (a, b) in candidates {
            let hits = samples
                .iter()
                .filter(|q| {
                    let poses = checker.robot.base_from_links(q);
                    checker.link_distance(&poses, a, b) < checker.margin_m
                })
                .count();
            if hits >= 95 {
                checker.skipped_pairs.push((
                    robot.links[a].clone(),
                    robot.links[b].clone(),
                    "always in contact",
                ));
            } else {
                checker.pairs.push((a, b));
            }
        }
        Ok(checker)
    }

    /// Joint names in joint-vector order.
    pub fn joint_names(&self) -> &[String] {
        &self.names
    }

    /// Allowed range per joint (URDF ∩ controller ∩ configured sub-range).
    pub fn limits(&self) -> &[(f64, f64)] {
        &self.limits
    }

    /// Highest speed the checker accepts, rad/s.
    pub fn speed_cap_rad_s(&self) -> f64 {
        self.velocity_caps
            .iter()
            .fold(self.speed_cap, |a, &b| a.min(b))
    }

    /// The robot checked.
    pub fn robot(&self) -> &Arc<RobotModel> {
        &self.robot
    }

    fn element_pose(&self, poses: &[Isometry3<f64>], e: usize) -> Isometry3<f64> {
        poses[self.collision.elements[e].link]
    }

    fn link_distance(&self, poses: &[Isometry3<f64>], a: usize, b: usize) -> f64 {
        let mut best = f64::INFINITY;
        for &ea in &self.collision.link_elements[a] {
            for &eb in &self.collision.link_elements[b] {
                let (pa, pb) = (self.element_pose(poses, ea), self.element_pose(poses, eb));
                let (xa, xb) = (&self.collision.elements[ea], &self.collision.elements[eb]);
                let centres = (pa * xa.centre - pb * xb.centre).norm();
                let lower = centres - xa.radius_m - xb.radius_m;
                if lower >= best.min(self.margin_m) {
                    best = best.min(lower);
                    continue;
                }
                let d = query::distance(&pa, &*xa.shape, &pb, &*xb.shape).unwrap_or(0.0);
                best = best.min(d);
            }
        }
        best
    }

    fn check_limits(&self, q: &[f64]) -> std::result::Result<(), Violation> {
        if q.len() != self.limits.len() {
            return Err(Violation::Malformed(format!(
                "{} values for {} joints",
                q.len(),
                self.limits.len()
            )));
        }
        for (k, (&v, &(lo, hi))) in q.iter().zip(&self.limits).enumerate() {
            if !v.is_finite() {
                return Err(Violation::Malformed(format!(
                    "joint {} is {v}",
                    self.names[k]
                )));
            }
            if v < lo || v > hi {
                return Err(Violation::JointLimit {
                    joint: self.names[k].clone(),
                    value: v,
                    range: (lo, hi),
                });
            }
        }
        Ok(())
    }

    /// Checks one pose: limits, workspace, environment and self clearance.
    pub fn check_pose(&self, q: &[f64]) -> std::result::Result<Clearance, Violation> {
        self.check_limits(q)?;
        let poses = self.robot.base_from_links(q);
        let mut clearance = Clearance {
            self_m: f64::INFINITY,
            environment_m: f64::INFINITY,
        };
        if let Some((centre, radius)) = self.workspace {
            for el in &self.collision.elements {
                let d = (poses[el.link] * el.centre - centre).norm();
                if d > radius {
                    return Err(Violation::Workspace {
                        link: self.robot.links[el.link].clone(),
                        distance_m: d,
                    });
                }
            }
        }
        for el in &self.collision.elements {
            if self.env_exempt_link[el.link] {
                continue;
            }
            let pose = poses[el.link];
            let centre = pose * el.centre;
            for o in &self.env {
                if let Some(aabb) = &o.aabb {
                    let lower = aabb.distance_to_local_point(&centre, true) - el.radius_m;
                    if lower >= self.margin_m {
                        clearance.environment_m = clearance.environment_m.min(lower);
                        continue;
                    }
                }
                let d = query::distance(&pose, &*el.shape, &o.pose, &*o.shape).unwrap_or(0.0);
                clearance.environment_m = clearance.environment_m.min(d);
                if d < self.margin_m {
                    return Err(Violation::Environment {
                        link: self.robot.links[el.link].clone(),
                        obstacle: o.name.clone(),
                        clearance_m: d,
                    });
                }
            }
        }
        for &(a, b) in &self.pairs {
            let d = self.link_distance(&poses, a, b);
            clearance.self_m = clearance.self_m.min(d);
            if d < self.margin_m {
                return Err(Violation::SelfCollision {
                    links: (self.robot.links[a].clone(), self.robot.links[b].clone()),
                    clearance_m: d,
                });
            }
        }
        Ok(clearance)
    }

    /// Poses checked on the line `from → to`: enough that no collision point moves more than
    /// half the margin between two of them.
    pub fn path_samples(&self, from: &[f64], to: &[f64]) -> usize {
        let sweep: f64 = from
            .iter()
            .zip(to)
            .zip(&self.joint_reach_m)
            .map(|((a, b), r)| (b - a).abs() * r)
            .sum();
        ((sweep / (self.margin_m / 2.0)).ceil() as usize).max(1)
    }

    /// Checks every pose on the joint-space line `from → to` (both ends included).
    pub fn check_path(
        &self,
        from: &[f64],
        to: &[f64],
    ) -> std::result::Result<(usize, Clearance), Violation> {
        self.check_limits(from)?;
        self.check_limits(to)?;
        let n = self.path_samples(from, to);
        let mut worst = Clearance {
            self_m: f64::INFINITY,
            environment_m: f64::INFINITY,
        };
        for i in 0..=n {
            let s = i as f64 / n as f64;
            let q: Vec<f64> = from.iter().zip(to).map(|(a, b)| a + (b - a) * s).collect();
            let c = self.check_pose(&q).map_err(|v| Violation::Path {
                at_fraction: s,
                inner: Box::new(v),
            })?;
            worst.self_m = worst.self_m.min(c.self_m);
            worst.environment_m = worst.environment_m.min(c.environment_m);
        }
        Ok((n + 1, worst))
    }

    /// The full check of a move from the arm's current pose.
    pub fn check_move(
        &self,
        from: &[f64],
        to: &[f64],
        speed_rad_s: f64,
    ) -> std::result::Result<CheckedMove, Violation> {
        let cap = self.speed_cap_rad_s();
        if !(speed_rad_s > 0.0 && speed_rad_s <= cap) {
            return Err(Violation::Speed {
                requested: speed_rad_s,
                cap,
            });
        }
        let (samples, clearance) = self.check_path(from, to)?;
        Ok(CheckedMove {
            from: from.to_vec(),
            to: to.to_vec(),
            speed_rad_s,
            samples,
            clearance,
        })
    }
}

/// Upper bound of how far any collision point moves per unit of each actuated joint: the
/// longest chain of joint offsets below the joint plus the farthest piece of a link there
/// (mimic followers add their multiplier's share).
fn joint_reach(robot: &RobotModel, collision: &CollisionModel) -> Vec<f64> {
    let link_reach = collision.link_reach_m();
    let n_links = robot.links.len();
    // Reach of each link's subtree measured from the link's own origin.
    let mut subtree = link_reach.clone();
    // Process joints children-first: repeat until stable (trees are shallow).
    for _ in 0..n_links {
        let mut changed = false;
        for j in &robot.joints {
            let via = j.parent_from_joint.translation.vector.norm() + subtree[j.child];
            if via > subtree[j.parent] + 1e-12 {
                subtree[j.parent] = via;
                changed = true;
            }
        }
        if !changed {
            break;
        }
    }
    let per_joint: Vec<f64> = robot
        .joints
        .iter()
        .map(|j| match j.kind {
            JointKind::Prismatic => 1.0,
            JointKind::Fixed => 0.0,
            _ => subtree[j.child],
        })
        .collect();
    robot
        .actuated
        .iter()
        .map(|&a| {
            let followers: f64 = robot
                .joints
                .iter()
                .enumerate()
                .filter_map(|(i, j)| match j.mimic {
                    Some((leader, mul, _)) if leader == a => Some(mul.abs() * per_joint[i]),
                    _ => None,
                })
                .sum();
            per_joint[a] + followers
        })
        .collect()
}

/// An arm that only accepts [`CheckedMove`]s, re-reading the joints first to make sure the
/// arm is still where the check assumed. The raw driver stays inside: a cell hands out only
/// this, so no code path can send a target the safety checker has not passed.
#[derive(Clone)]
pub struct SafeArm {
    arm: Arc<dyn easyhec_drivers::Arm>,
    /// Largest difference between the checked start and the arm's reading, radians.
    pub start_tolerance_rad: f64,
}

impl SafeArm {
    /// Wraps `arm`.
    pub fn new(arm: Arc<dyn easyhec_drivers::Arm>) -> SafeArm {
        SafeArm {
            arm,
            start_tolerance_rad: 0.01,
        }
    }

    /// The controller's joint limits and speeds.
    pub fn joints(&self) -> &[easyhec_drivers::JointLimit] {
        self.arm.joints()
    }

    /// Reads the joints as the controller reports them.
    pub async fn read_joints(&self) -> Result<Vec<f64>> {
        Ok(self.arm.read_joints().await?)
    }

    /// The controller's state.
    pub async fn status(&self) -> Result<easyhec_drivers::ArmStatus> {
        Ok(self.arm.status().await?)
    }

    /// Stops any motion (always allowed: stopping never needs a check).
    pub async fn stop(&self) -> Result<()> {
        Ok(self.arm.stop().await?)
    }

    /// Clears a fault so the arm accepts moves again.
    pub async fn clear_fault(&self) -> Result<()> {
        Ok(self.arm.clear_fault().await?)
    }

    /// Sends a checked move.
    pub async fn execute(&self, mv: &CheckedMove) -> Result<easyhec_drivers::Motion> {
        let now = self
            .arm
            .read_joints()
            .await
            .map_err(|e| Error::driver("reading joints before a move", e))?;
        let drift = now
            .iter()
            .zip(mv.from())
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        if now.len() != mv.from().len() || drift > self.start_tolerance_rad {
            return Err(Error::Hardware(format!(
                "the arm moved {drift:.4} rad since its path was checked; not moving"
            )));
        }
        self.arm
            .move_to(mv.to(), mv.speed_rad_s())
            .await
            .map_err(|e| Error::driver("arm", e))
    }
}
