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
//!
//! Layout: this file holds the public types; `build` turns the `[safety]` config into a
//! checker, `checker` runs the checks, and `arm` is the arm that only takes checked moves.

use std::sync::Arc;

use nalgebra::{Isometry3, Point3};
use parry3d_f64::bounding_volume::Aabb;
use parry3d_f64::shape::SharedShape;

use crate::collision::CollisionModel;
use crate::robot::RobotModel;

mod arm;
mod build;
mod checker;

pub use arm::SafeArm;
pub use build::read_srdf_disabled_pairs;

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
        /// The `[[safety.attached]]` bodies of those links that came closest, if the closest
        /// pieces were attached bodies rather than the URDF's own.
        bodies: (Option<String>, Option<String>),
        /// Clearance, metres.
        clearance_m: f64,
    },
    /// A link closer than the margin to an obstacle (or inside a keep-out zone).
    Environment {
        /// Link name.
        link: String,
        /// The link's attached body that came too close, if it was one.
        body: Option<String>,
        /// Obstacle label.
        obstacle: String,
        /// Clearance, metres.
        clearance_m: f64,
    },
    /// A link outside the workspace ball.
    Workspace {
        /// Link name.
        link: String,
        /// The link's attached body that left the ball, if it was one.
        body: Option<String>,
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

/// A collision piece as messages name it: `link link3`, or `wrist camera (attached to link6)`.
fn piece(link: &str, body: &Option<String>) -> String {
    match body {
        Some(body) => format!("{body} (attached to {link})"),
        None => format!("link {link}"),
    }
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
            Violation::SelfCollision {
                links,
                bodies,
                clearance_m,
            } => write!(
                f,
                "{} and {} within {:.1} mm",
                piece(&links.0, &bodies.0),
                piece(&links.1, &bodies.1),
                clearance_m * 1e3
            ),
            Violation::Environment {
                link,
                body,
                obstacle,
                clearance_m,
            } => write!(
                f,
                "{} within {:.1} mm of {obstacle}",
                piece(link, body),
                clearance_m * 1e3
            ),
            Violation::Workspace {
                link,
                body,
                distance_m,
            } => write!(
                f,
                "{} {:.3} m from the workspace centre",
                piece(link, body),
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

/// One environment obstacle, placed, with its bounding box for a cheap lower bound
/// (planes have none: they are unbounded).
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
