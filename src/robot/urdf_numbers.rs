//! Range checks on every number a URDF carries, run before any of them is used.
//!
//! A NaN in an `<origin>` or a zero mesh `scale` does not fail later: the kinematics and the
//! renderer would carry it silently, the link would vanish or sit at the wrong place, and a
//! solve would fit the wrong robot with a tight uncertainty. So each value is checked here, and
//! the message names the element the way a reader finds it in the file.

use std::path::Path;

use crate::error::{Error, Result};

/// Smallest mesh scale magnitude accepted: below this a mesh collapses to a point.
const MIN_MESH_SCALE: f64 = 1e-6;

/// Checks every joint and link number of `urdf`; the first problem is the error.
pub(crate) fn check(urdf: &urdf_rs::Robot, urdf_path: &Path) -> Result<()> {
    for j in &urdf.joints {
        check_joint(j, urdf_path)?;
    }
    for link in &urdf.links {
        for (i, v) in link.visual.iter().enumerate() {
            let at = format!("link '{}' visual {i}", link.name);
            check_pose(&v.origin, &at, urdf_path)?;
            check_geometry(&v.geometry, &at, urdf_path)?;
        }
        for (i, c) in link.collision.iter().enumerate() {
            let at = format!("link '{}' collision {i}", link.name);
            check_pose(&c.origin, &at, urdf_path)?;
            check_geometry(&c.geometry, &at, urdf_path)?;
        }
    }
    Ok(())
}

fn check_joint(j: &urdf_rs::Joint, urdf_path: &Path) -> Result<()> {
    let at = format!("joint '{}'", j.name);
    check_pose(&j.origin, &at, urdf_path)?;
    finite3(&j.axis.xyz.0, &format!("{at} axis xyz"), urdf_path)?;
    let movable = matches!(
        j.joint_type,
        urdf_rs::JointType::Revolute | urdf_rs::JointType::Prismatic
    );
    if movable {
        let limit = &j.limit;
        for (name, v) in [("lower", limit.lower), ("upper", limit.upper)] {
            if !v.is_finite() {
                return Err(bad(
                    urdf_path,
                    &format!("{at} limit {name}"),
                    v,
                    "a finite number",
                ));
            }
        }
        if limit.lower > limit.upper {
            return Err(Error::input(
                urdf_path,
                format!("{at} limit"),
                format!(
                    "lower {} is above upper {}: swap them",
                    limit.lower, limit.upper
                ),
            ));
        }
    }
    if !(j.limit.velocity.is_finite() && j.limit.velocity >= 0.0) {
        let v = j.limit.velocity;
        return Err(bad(
            urdf_path,
            &format!("{at} limit velocity"),
            v,
            "a finite speed >= 0",
        ));
    }
    if let Some(m) = &j.mimic {
        for (name, v) in [("multiplier", m.multiplier), ("offset", m.offset)] {
            if let Some(v) = v.filter(|v| !v.is_finite()) {
                return Err(bad(
                    urdf_path,
                    &format!("{at} mimic {name}"),
                    v,
                    "a finite number",
                ));
            }
        }
    }
    Ok(())
}

fn check_pose(pose: &urdf_rs::Pose, at: &str, urdf_path: &Path) -> Result<()> {
    finite3(&pose.xyz.0, &format!("{at} origin xyz"), urdf_path)?;
    finite3(&pose.rpy.0, &format!("{at} origin rpy"), urdf_path)
}

fn check_geometry(g: &urdf_rs::Geometry, at: &str, urdf_path: &Path) -> Result<()> {
    let positive = |name: &str, v: f64| -> Result<()> {
        if v.is_finite() && v > 0.0 {
            Ok(())
        } else {
            Err(bad(
                urdf_path,
                &format!("{at} {name}"),
                v,
                "a finite length > 0 (metres)",
            ))
        }
    };
    match g {
        urdf_rs::Geometry::Box { size } => {
            for v in size.0 {
                positive("box size", v)?;
            }
        }
        urdf_rs::Geometry::Cylinder { radius, length }
        | urdf_rs::Geometry::Capsule { radius, length } => {
            positive("radius", *radius)?;
            positive("length", *length)?;
        }
        urdf_rs::Geometry::Sphere { radius } => positive("radius", *radius)?,
        urdf_rs::Geometry::Mesh { scale, .. } => {
            for v in scale.map(|s| s.0).unwrap_or([1.0; 3]) {
                if !(v.is_finite() && v.abs() >= MIN_MESH_SCALE) {
                    return Err(bad(
                        urdf_path,
                        &format!("{at} mesh scale"),
                        v,
                        "finite and non-zero (e.g. 0.001 for a mesh in millimetres)",
                    ));
                }
            }
        }
    }
    Ok(())
}

fn finite3(v: &[f64; 3], at: &str, urdf_path: &Path) -> Result<()> {
    match v.iter().find(|x| !x.is_finite()) {
        Some(x) => Err(bad(urdf_path, at, *x, "finite numbers")),
        None => Ok(()),
    }
}

fn bad(urdf_path: &Path, at: &str, got: f64, allowed: &str) -> Error {
    Error::input(urdf_path, at, format!("is {got}; allowed: {allowed}"))
}
