//! The checks: joint limits, workspace, environment and self clearance of a pose, then of
//! every sampled pose on a joint-space line, then the full move with its speed.

use std::sync::Arc;

use nalgebra::Isometry3;
use parry3d_f64::query::{self, PointQuery};

use super::{CheckedMove, Clearance, SafetyChecker, Violation};
use crate::robot::RobotModel;

impl SafetyChecker {
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

    /// Piece `e`'s link name and attached body's name (if it is one), for messages.
    fn piece_names(&self, e: usize) -> (String, Option<String>) {
        let el = &self.collision.elements[e];
        (self.robot.links[el.link].clone(), el.attached.clone())
    }

    /// Smallest distance between two links' pieces (bounding-ball shortcut first), with the
    /// two pieces it was found between; shared with the build step that finds
    /// always-in-contact pairs, which leaves attached bodies out (`with_attached` false).
    pub(super) fn link_distance(
        &self,
        poses: &[Isometry3<f64>],
        (a, b): (usize, usize),
        with_attached: bool,
    ) -> (f64, (usize, usize)) {
        let pieces = |l: usize| {
            self.collision.link_elements[l]
                .iter()
                .copied()
                .filter(move |&e| with_attached || self.collision.elements[e].attached.is_none())
        };
        let mut best = (f64::INFINITY, (usize::MAX, usize::MAX));
        for ea in pieces(a) {
            for eb in pieces(b) {
                let (pa, pb) = (self.element_pose(poses, ea), self.element_pose(poses, eb));
                let (xa, xb) = (&self.collision.elements[ea], &self.collision.elements[eb]);
                let centres = (pa * xa.centre - pb * xb.centre).norm();
                let lower = centres - xa.radius_m - xb.radius_m;
                let d = if lower >= best.0.min(self.margin_m) {
                    lower
                } else {
                    query::distance(&pa, &*xa.shape, &pb, &*xb.shape).unwrap_or(0.0)
                };
                if d < best.0 {
                    best = (d, (ea, eb));
                }
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
            for (e, el) in self.collision.elements.iter().enumerate() {
                let d = (poses[el.link] * el.centre - centre).norm();
                if d > radius {
                    let (link, body) = self.piece_names(e);
                    return Err(Violation::Workspace {
                        link,
                        body,
                        distance_m: d,
                    });
                }
            }
        }
        for (e, el) in self.collision.elements.iter().enumerate() {
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
                    let (link, body) = self.piece_names(e);
                    return Err(Violation::Environment {
                        link,
                        body,
                        obstacle: o.name.clone(),
                        clearance_m: d,
                    });
                }
            }
        }
        for &(a, b) in &self.pairs {
            let (d, (ea, eb)) = self.link_distance(&poses, (a, b), true);
            clearance.self_m = clearance.self_m.min(d);
            if d < self.margin_m {
                let ((link_a, body_a), (link_b, body_b)) =
                    (self.piece_names(ea), self.piece_names(eb));
                return Err(Violation::SelfCollision {
                    links: (link_a, link_b),
                    bodies: (body_a, body_b),
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
