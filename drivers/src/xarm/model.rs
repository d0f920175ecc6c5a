//! UFACTORY arm models and the joint limits their controllers enforce (docs/protocols.md §1.9).

use std::f64::consts::{PI, TAU};
use std::fmt;
use std::str::FromStr;

/// A UFACTORY arm model: decides the axis count and the joint limits the driver enforces on
/// its own, before the controller sees a command.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Model {
    /// xArm 5 (device type 5).
    Xarm5,
    /// xArm 6 (device type 6).
    Xarm6,
    /// xArm 6 with serial number 1305 or later (slightly narrower J2/J3).
    Xarm6Sn1305,
    /// xArm 7 (device type 7).
    Xarm7,
    /// Lite 6 (device type 9).
    Lite6,
    /// UF850 (device type 12).
    Uf850,
}

impl Model {
    /// Every model, in the order the config names are listed in errors.
    pub const ALL: [Model; 6] = [
        Model::Xarm5,
        Model::Xarm6,
        Model::Xarm6Sn1305,
        Model::Xarm7,
        Model::Lite6,
        Model::Uf850,
    ];

    /// The config name (`xarm6`, `lite6`, …).
    pub fn name(self) -> &'static str {
        match self {
            Model::Xarm5 => "xarm5",
            Model::Xarm6 => "xarm6",
            Model::Xarm6Sn1305 => "xarm6-sn1305",
            Model::Xarm7 => "xarm7",
            Model::Lite6 => "lite6",
            Model::Uf850 => "uf850",
        }
    }

    /// Actuated joints.
    pub fn axes(self) -> usize {
        match self {
            Model::Xarm5 => 5,
            Model::Xarm7 => 7,
            _ => 6,
        }
    }

    /// The device type the controller reports in its version string.
    pub fn device_type(self) -> u8 {
        match self {
            Model::Xarm5 => 5,
            Model::Xarm6 | Model::Xarm6Sn1305 => 6,
            Model::Xarm7 => 7,
            Model::Lite6 => 9,
            Model::Uf850 => 12,
        }
    }

    /// Joint limits (lower, upper) in radians, J1 first.
    pub fn joint_limits(self) -> Vec<(f64, f64)> {
        let full = (-TAU, TAU);
        match self {
            Model::Xarm6 => vec![
                full,
                (-2.059488, 2.094395),
                (-3.92699, 0.191986),
                full,
                (-1.692969, PI),
                full,
            ],
            Model::Xarm6Sn1305 => vec![
                full,
                (-2.042035, 2.024581),
                (-3.822271, 0.174532),
                full,
                (-1.692969, PI),
                full,
            ],
            Model::Xarm5 => vec![
                full,
                (-2.059488, 2.094395),
                (-3.92699, 0.191986),
                (-1.692969, PI),
                full,
            ],
            Model::Xarm7 => vec![
                full,
                (-2.059488, 2.094395),
                full,
                (-0.191986, 3.92699),
                full,
                (-1.692969, PI),
                full,
            ],
            Model::Lite6 => vec![
                full,
                (-2.617994, 2.617994),
                (-0.061087, 5.235988),
                full,
                (-2.164208, 2.164208),
                full,
            ],
            Model::Uf850 => vec![
                full,
                (-2.303835, 2.303835),
                (-4.223697, 0.061087),
                full,
                (-2.164208, 2.164208),
                full,
            ],
        }
    }
}

impl fmt::Display for Model {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Model {
    type Err = String;

    fn from_str(s: &str) -> Result<Model, String> {
        let key = s.trim().to_ascii_lowercase().replace(['_', ' '], "-");
        let alias = match key.as_str() {
            "xarm-5" => "xarm5",
            "xarm-6" => "xarm6",
            "xarm-7" => "xarm7",
            "lite-6" => "lite6",
            "850" | "uf-850" => "uf850",
            k => k,
        };
        Model::ALL
            .into_iter()
            .find(|m| m.name() == alias)
            .ok_or_else(|| {
                let names: Vec<&str> = Model::ALL.iter().map(|m| m.name()).collect();
                format!("unknown xArm model `{s}`: use one of {}", names.join(", "))
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_model_has_one_limit_per_axis_and_parses_back() {
        for m in Model::ALL {
            let l = m.joint_limits();
            assert_eq!(l.len(), m.axes(), "{m}");
            assert!(l.iter().all(|(lo, hi)| lo < hi && lo.is_finite()));
            assert_eq!(m.name().parse::<Model>().unwrap(), m);
        }
        assert_eq!("UF850".parse::<Model>().unwrap(), Model::Uf850);
        assert_eq!("xArm 6".parse::<Model>().unwrap(), Model::Xarm6);
        let e = "xarm9".parse::<Model>().unwrap_err();
        assert!(e.contains("xarm9") && e.contains("lite6"), "{e}");
        // J3 of a Lite 6 reaches 300°, of a UF850 −242°.
        assert!((Model::Lite6.joint_limits()[2].1.to_degrees() - 300.0).abs() < 1e-3);
        assert!((Model::Uf850.joint_limits()[2].0.to_degrees() + 242.0).abs() < 1e-3);
    }
}
