//! Building a [`SafetyChecker`] from the `[safety]` config: validated limits and caps, the
//! link pairs never checked (and why), the environment obstacles and the workspace ball.

use std::path::Path;
use std::sync::Arc;

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use parry3d_f64::shape::{Ball, Cuboid, HalfSpace, SharedShape};
use rand::{Rng, SeedableRng};

use super::{EnvShape, SafetyChecker};
use crate::collision::{bounding_sphere, hull_of, CollisionModel};
use crate::config::{AttachedConfig, ObstacleConfig, SafetyConfig};
use crate::error::{Error, Result};
use crate::mesh::load_mesh_file;
use crate::robot::{JointKind, RobotModel};

/// Per link pair, why it is never checked (`None`: checked unless always in contact).
type SkipTable = Vec<Vec<Option<&'static str>>>;

/// Allowed `(lower, upper)` range and speed cap (rad/s) per actuated joint.
type LimitsAndCaps = (Vec<(f64, f64)>, Vec<f64>);

/// Config field name under `[safety]`, for error messages.
fn field(f: &str) -> String {
    format!("safety.{f}")
}

/// Pose from a config's position and roll-pitch-yaw in degrees.
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
    let text = crate::io::read_text_input(path)?;
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
        check_margin_and_speed(cfg, config_path)?;
        let mut collision = CollisionModel::load(&robot)?;
        attach_bodies(&mut collision, &robot, cfg, config_path, config_dir)?;
        let names: Vec<String> = robot.joint_names().iter().map(|s| s.to_string()).collect();
        let (limits, velocity_caps) =
            joint_limits_and_caps(&robot, cfg, controller_limits, &names, config_path)?;
        let n_links = robot.links.len();
        let groups = rigid_groups(&robot);
        let skip = skip_table(&robot, cfg, &groups, config_path, config_dir)?;
        let env = cfg
            .obstacles
            .iter()
            .enumerate()
            .map(|(i, o)| obstacle(i, o, config_path, config_dir))
            .collect::<Result<Vec<_>>>()?;
        // The base's rigid group cannot be moved by a command: it is exempt from environment
        // checks (it stands on the table by design).
        let base_group = groups[robot.base];
        let env_exempt_link: Vec<bool> = (0..n_links).map(|l| groups[l] == base_group).collect();
        let workspace = workspace(cfg, config_path)?;

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
        checker.select_pairs(&skip);
        Ok(checker)
    }

    /// Fills `pairs` and `skipped_pairs`: pairs the table skips, and "always in collision"
    /// pairs (MoveIt's setup-assistant rule), found from 100 seeded random poses.
    fn select_pairs(&mut self, skip: &SkipTable) {
        let robot = self.robot.clone();
        let n_links = robot.links.len();
        // "Always in collision" pairs (MoveIt's setup-assistant rule): in contact in nearly
        // every random pose, so the geometry overlaps by construction (simplified shapes).
        let mut candidates = Vec::new();
        #[allow(clippy::needless_range_loop)] // a symmetric pair table, indexed both ways
        for a in 0..n_links {
            for b in a + 1..n_links {
                let has = |l: usize| !self.collision.link_elements[l].is_empty();
                if !has(a) || !has(b) {
                    continue;
                }
                match skip[a][b] {
                    Some(why) => self.skipped_pairs.push((
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
                self.limits
                    .iter()
                    .map(|&(lo, hi)| rng.random_range(lo..=hi))
                    .collect()
            })
            .collect();
        for (a, b) in candidates {
            let hits = samples
                .iter()
                .filter(|q| {
                    let poses = self.robot.base_from_links(q);
                    self.link_distance(&poses, (a, b), false).0 < self.margin_m
                })
                .count();
            if hits >= 95 {
                self.skipped_pairs.push((
                    robot.links[a].clone(),
                    robot.links[b].clone(),
                    "always in contact",
                ));
            } else {
                self.pairs.push((a, b));
            }
        }
    }
}

/// Rejects a margin or speed cap that would make every check meaningless.
fn check_margin_and_speed(cfg: &SafetyConfig, config_path: &Path) -> Result<()> {
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
    Ok(())
}

/// Allowed range (URDF ∩ controller ∩ configured sub-range) and speed cap per actuated
/// joint; a configured range naming no actuated joint is an error, not silently ignored.
fn joint_limits_and_caps(
    robot: &RobotModel,
    cfg: &SafetyConfig,
    controller_limits: &[(f64, f64, f64)],
    names: &[String],
    config_path: &Path,
) -> Result<LimitsAndCaps> {
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
    Ok((limits, velocity_caps))
}

/// Rigid group (a representative link) per link: links joined by fixed joints move together.
fn rigid_groups(robot: &RobotModel) -> Vec<usize> {
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
    (0..n_links).map(|l| find(&mut group, l)).collect()
}

/// Which link pairs are never checked, and why: rigidly attached, adjacent, allowed in the
/// config or disabled in the SRDF.
fn skip_table(
    robot: &RobotModel,
    cfg: &SafetyConfig,
    groups: &[usize],
    config_path: &Path,
    config_dir: &Path,
) -> Result<SkipTable> {
    let n_links = robot.links.len();
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
    Ok(skip)
}

/// Farthest an attached body may reach from its link's origin, metres. Why: the path check
/// samples a move finely enough for its farthest piece, so a body given in millimetres by
/// mistake would make every move thousands of samples long instead of failing.
const ATTACHED_REACH_M: f64 = 2.0;

/// Adds every `[[safety.attached]]` body to its link's pieces, before the pair table and the
/// joints' reach are worked out, so both count it.
fn attach_bodies(
    collision: &mut CollisionModel,
    robot: &RobotModel,
    cfg: &SafetyConfig,
    config_path: &Path,
    config_dir: &Path,
) -> Result<()> {
    for (i, body) in cfg.attached.iter().enumerate() {
        let at = |f: &str| field(&format!("attached[{i}].{f}"));
        let link = robot.link_index(body.link()).ok_or_else(|| {
            Error::input(
                config_path,
                at("link"),
                format!("no link named '{}' in the URDF", body.link()),
            )
        })?;
        let (shape, bound) = attached_shape(body, config_dir)?
            .ok_or_else(|| Error::input(config_path, at("file"), "mesh has no vertices"))?;
        let reach_m = bound.0.coords.norm() + bound.1;
        if reach_m > ATTACHED_REACH_M {
            return Err(Error::input(
                config_path,
                field(&format!("attached[{i}]")),
                format!("reaches {reach_m:.3} m from the origin of link '{}'; allowed: at most {ATTACHED_REACH_M} m (a millimetre mesh needs scale = [0.001, 0.001, 0.001])", body.link()),
            ));
        }
        collision.attach(link, body.name(), shape, bound);
    }
    Ok(())
}

/// A config's mesh file (relative to the config), its vertices scaled per axis.
fn scaled_mesh_points(
    config_dir: &Path,
    file: &Path,
    scale: &[f64; 3],
) -> Result<Vec<Point3<f64>>> {
    let mesh = load_mesh_file(&config_dir.join(file))?;
    let scale = Vector3::from(*scale);
    Ok(mesh
        .vertices
        .iter()
        .map(|p| Point3::from(p.coords.component_mul(&scale)))
        .collect())
}

/// A piece's shape in its link's frame and its bounding ball there.
type LinkPiece = (SharedShape, (Point3<f64>, f64));

/// An attached body's shape in its link's frame and its bounding ball there (`None` for a
/// mesh without vertices).
fn attached_shape(body: &AttachedConfig, config_dir: &Path) -> Result<Option<LinkPiece>> {
    let placed = |pose: Isometry3<f64>, points: Vec<Point3<f64>>| {
        let points: Vec<Point3<f64>> = points.iter().map(|p| pose * p).collect();
        Ok(hull_of(&points).map(|hull| (hull, bounding_sphere(&points))))
    };
    match body {
        AttachedConfig::Box {
            size, xyz, rpy_deg, ..
        } => {
            let half = Vector3::from(*size) / 2.0;
            let corners = (0..8)
                .map(|k| {
                    let s = |bit: usize| if k & bit == 0 { -1.0 } else { 1.0 };
                    Point3::new(s(1) * half.x, s(2) * half.y, s(4) * half.z)
                })
                .collect();
            placed(pose_from(*xyz, *rpy_deg), corners)
        }
        AttachedConfig::Sphere { radius_m, xyz, .. } => {
            let centre = Point3::from(*xyz);
            let ball = SharedShape::compound(vec![(
                Isometry3::from(centre.coords),
                SharedShape::new(Ball::new(*radius_m)),
            )]);
            Ok(Some((ball, (centre, *radius_m))))
        }
        AttachedConfig::Mesh {
            file,
            xyz,
            rpy_deg,
            scale,
            ..
        } => placed(
            pose_from(*xyz, *rpy_deg),
            scaled_mesh_points(config_dir, file, scale)?,
        ),
    }
}

/// Obstacle `i` of the config, placed, with its bounding box (none for planes).
fn obstacle(
    i: usize,
    o: &ObstacleConfig,
    config_path: &Path,
    config_dir: &Path,
) -> Result<EnvShape> {
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
            let pts = scaled_mesh_points(config_dir, file, scale)?;
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
    Ok(EnvShape {
        name,
        pose,
        shape,
        aabb,
    })
}

/// The optional workspace ball `(centre, radius)`.
fn workspace(cfg: &SafetyConfig, config_path: &Path) -> Result<Option<(Point3<f64>, f64)>> {
    Ok(match &cfg.workspace {
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
    })
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
